#!/usr/bin/env bash
# Issue #12's GPU figures in one run, for a session on a GPU machine
# (docs/BENCHMARKS.md says what each is for): the tracer alone, bakes end to
# end with their event times, SH, and a queue through lightfarmd. Every
# result is a file in OUT; nothing here is estimated.
#   bench/gpu_figures.sh OUT [--device gpu|cpu] [--quick]
# --quick: small sizes, to check the script itself on llvmpipe (--device cpu).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
scenes="${LIGHTFARM_SCENES:-$root/examples}"
lightfarm="$root/build/client_cli/lightfarm"
out="$1"; shift
device=gpu quick=0
while [ $# -gt 0 ]; do
  case "$1" in
    --device) device="$2"; shift 2 ;;
    --quick) quick=1; shift ;;
    *) echo "unknown option $1" >&2; exit 2 ;;
  esac
done
mkdir -p "$out"
staircase=real/wooden_staircase/wooden_staircase.gltf
if [ "$quick" = 1 ]; then
  seconds=0.5 cornell="--res 64 --passes 16" spheres="--res 128 --passes 8" stairs="--res 512 --passes 2"
  sh_passes=1 jobs=2 job_res=64 job_passes=16
else
  seconds=3 cornell="--res 512 --passes 800" spheres="--res 1024 --passes 256" stairs="--res 1024 --passes 1024"
  sh_passes=16 jobs=8 job_res=512 job_passes=800
fi

"$lightfarm" devices --json > "$out/devices.json"
# The tracer alone: incoherent and coherent closest-hit rays per second (one JSON object per scene).
for scene in cornell_box.gltf monkey.glb spheres.glb $staircase real/breakfast_room/breakfast_room.gltf; do
  "$lightfarm" raybench "$scenes/$scene" --device "$device" --seconds "$seconds" >> "$out/raybench.json"
done
# Bakes end to end: the time each event arrived, the manifest's stages.
bake() {  # NAME SCENE ARGS...
  local name="$1" scene="$2"; shift 2
  rm -rf "$out/$name"
  /usr/bin/time -v python3 "$root/bench/timed_events.py" "$lightfarm" bake "$scenes/$scene" --out "$out/$name" \
    --device "$device" --json "$@" > "$out/$name.events" 2> "$out/$name.time"
  rm -f "$out/$name"/*.pass-*.exr  # the snapshots: many, large, and not what is measured
}
# shellcheck disable=SC2086
bake cornell cornell_box.gltf $cornell
# The same with one pass per dispatch: what several passes per dispatch save (the default is auto).
# shellcheck disable=SC2086
bake cornell_one_pass_per_dispatch cornell_box.gltf $cornell --passes-per-dispatch 1
# shellcheck disable=SC2086
bake spheres spheres.glb $spheres
# shellcheck disable=SC2086
bake staircase $staircase $stairs
bake sh_breakfast real/breakfast_room/breakfast_room.gltf --sh --sh-bands 4 --sh-passes "$sh_passes"
# A queue of bakes through the service: how busy it keeps the device.
if [ "$device" = gpu ]; then workers=(); else workers=(--workers 1); fi
python3 "$root/bench/service_busy.py" "$out/service" --jobs "$jobs" --res "$job_res" --passes "$job_passes" \
  "${workers[@]}" > "$out/service.json"
rm -rf "$out/service/jobs" "$out/service/scenes"
echo "figures in $out"
