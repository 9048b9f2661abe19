stage "thread sanitizer: the service's end"
if ! wait "$tsan_tests"; then
  cat "$tsan_log"
  echo "scripts/test: the thread sanitizer's tests failed (above; $tsan_log)" >&2
  exit 1
fi
trap - EXIT
grep -E '^\[  (PASSED|FAILED) |tests? from .* ran' "$tsan_log" || true
