#!/usr/bin/env bash
# Texels where the light changes (atlas.light_density, issue #35): a scene's
# default bake and the same with --light-density (as many texels, placed by
# a first look at the light), each compared at points of the surface
# (`lightfarm compare BAKE_DIR REFERENCE_DIR`: the atlases differ) against
# one path-traced reference at REF_RES (finer than both, so that its own
# texels' blur is not what is measured), REF_PASSES passes of another seed.
#   bench/light_density.sh SCENE REF_RES [OUT_DIR] [bake args…]
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${LIGHTFARM:-build/client_cli/lightfarm}
SCENE=$1
REF_RES=$2
OUT=${3:-/tmp/lf-light-density}
shift $(( $# >= 3 ? 3 : 2 ))
REF_PASSES=${REF_PASSES:-256}
NAME=$(basename "${SCENE%.*}")
mkdir -p "$OUT/$NAME"

bake_once() {  # DIR ARGS…: bakes unless DIR holds a finished bake
    local dir=$1
    shift
    [ -f "$dir/manifest.json" ] && return 0
    "$BIN" bake "$SCENE" "$@" --out "$dir" > "$dir.log" 2>&1
}

bake_once "$OUT/$NAME/reference" --res "$REF_RES" --scheme pathtrace --passes "$REF_PASSES" --seed 7919 --no-denoise "$@"
bake_once "$OUT/$NAME/uniform" "$@"
bake_once "$OUT/$NAME/light-density" --light-density "$@"
for bake in uniform light-density; do
    for layer in final raw; do
        args=()
        [ "$layer" = raw ] && args+=(--layer raw)
        printf '%s %s %s: ' "$NAME" "$bake" "$layer"
        "$BIN" compare "$OUT/$NAME/$bake" "$OUT/$NAME/reference" "${args[@]}"
    done
done
