# Shared by scripts/run and scripts/test: install what is missing, then build.
# Sourced, not run.

LIGHTFARM_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"

# Debian 12 packages the build, the tests and the service need.
LIGHTFARM_PACKAGES=(
  build-essential cmake pkg-config
  libegl-dev libgl-dev libepoxy-dev libegl-mesa0 libgl1-mesa-dri
  libtinygltf-dev nlohmann-json3-dev libstb-dev libglm-dev libopenexr-dev zlib1g-dev
  libgtest-dev libcpp-httplib-dev libsqlite3-dev libssl-dev libpq-dev
)

# Installs only the packages that are not installed yet (apt-get only when needed).
ensure_packages() {
  local missing=()
  local p
  for p in "${LIGHTFARM_PACKAGES[@]}" "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
  done
  if [ ${#missing[@]} -gt 0 ]; then
    echo "lightfarm: installing ${missing[*]}" >&2
    local sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >&2
  fi
}

# The status page's three.js, and the tests' glTF validator and browser
# driver, from the npm registry at the versions web/package-lock.json pins,
# into web/node_modules (again only when the lock file changed). Node.js and
# npm from Debian when this machine has no npm.
ensure_web_packages() {
  command -v npm >/dev/null || ensure_packages nodejs npm
  local stamp="$LIGHTFARM_ROOT/web/node_modules/.package-lock.json"
  if [ ! -f "$stamp" ] || [ "$LIGHTFARM_ROOT/web/package-lock.json" -nt "$stamp" ]; then
    echo "lightfarm: installing web/package-lock.json's packages (three.js, gltf-validator, playwright-core)" >&2
    (cd "$LIGHTFARM_ROOT/web" && npm ci --no-audit --no-fund --loglevel=error) >&2
  fi
}

# build_tree DIR [cmake options...]: configure once, then build incrementally
# (only $LIGHTFARM_TARGETS when set, e.g. "lightfarmd lightfarm").
build_tree() {
  local dir="$1"; shift
  if [ ! -f "$dir/CMakeCache.txt" ]; then
    cmake -S "$LIGHTFARM_ROOT" -B "$dir" -DCMAKE_BUILD_TYPE=RelWithDebInfo "$@" >&2
  fi
  local targets=()
  local t
  for t in ${LIGHTFARM_TARGETS:-}; do targets+=(--target "$t"); done
  cmake --build "$dir" -j "$(nproc)" "${targets[@]}" >&2
}
