#!/usr/bin/env bash
# Pictures of a bake as a person sees it: bakes SCENE with `lightfarm bake`
# and the given settings into OUT_DIR, then opens its scene.lit.glb in a
# throwaway lightfarmd's status page (headless Chromium, the file's own
# camera and exposure) and saves OUT_DIR/lit.png and OUT_DIR/lightmap.png (the
# light alone on white surfaces: where blotches and streaks show).
#   bench/lightmap_view.sh SCENE OUT_DIR [bake settings…]
# The README's staircase pictures: the staircase at the defaults, and with
# --no-denoise (docs/images/staircase_*).
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${LIGHTFARM_BUILD:-build}
SCENE=$(realpath "$1")
OUT=$(realpath -m "$2")
shift 2
mkdir -p "$OUT"
# A folder that holds a finished bake is looked at as it is.
[ -f "$OUT/manifest.json" ] || "$BUILD/client_cli/lightfarm" bake "$SCENE" --out "$OUT" "$@" > /dev/null

data=$(mktemp -d)
trap 'kill "$server" 2> /dev/null; wait "$server" 2> /dev/null; rm -rf "$data"' EXIT
echo "lightfarm-view-$RANDOM$RANDOM" > "$data/tokens"
"$BUILD/server/lightfarmd" --data "$data" --tokens "$data/tokens" --listen 127.0.0.1:0 > "$data/log" 2>&1 &
server=$!
for _ in $(seq 100); do [ -s "$data/lightfarmd.url" ] && break; sleep 0.1; done
url=$(cat "$data/lightfarmd.url")
for mode in lit lightmap; do
    node bench/lightmap_view.mjs "$url" "$(cat "$data/tokens")" "$OUT/scene.lit.glb" "$mode" "$OUT/$mode.png"
done
