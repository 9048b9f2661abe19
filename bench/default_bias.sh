#!/usr/bin/env bash
# The default bake's bias against a converged reference (issue #35's "done
# when"): each scene baked with no setting but what the scene needs (a sky
# for the rooms lit through windows), and the path tracer at the same atlas
# (`--res auto` picks the same one), REF_PASSES passes of another seed, raw.
# Prints `lightfarm compare` of the final (denoised) map and of its raw
# layer, texel by texel and in 8x8 blocks (--block 8: low-frequency error,
# the blotches, with the reference's own noise averaged over the block).
#   bench/default_bias.sh [OUT_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${LIGHTFARM:-build/client_cli/lightfarm}
SCENES=$(realpath examples)
OUT=${1:-/tmp/lf-default-bias}
REF_PASSES=${REF_PASSES:-512}
mkdir -p "$OUT"

bake_once() {  # DIR SCENE ARGS…: bakes unless DIR holds a finished bake
    local dir=$1
    shift
    [ -f "$dir/manifest.json" ] && return 0
    mkdir -p "$(dirname "$dir")"
    "$BIN" bake "$@" --out "$dir" > "$dir.log" 2>&1
}

measure() {  # NAME SCENE [--env R,G,B]
    local name=$1 scene=$SCENES/$2
    shift 2
    bake_once "$OUT/$name/default" "$scene" "$@"
    bake_once "$OUT/$name/reference" "$scene" "$@" --scheme pathtrace --passes "$REF_PASSES" --seed 7919 --no-denoise
    for layer in final raw; do
        for block in 1 8; do
            local args=(--block "$block")
            [ "$layer" = raw ] && args+=(--layer raw)
            printf '%s %s block %s: ' "$name" "$layer" "$block"
            "$BIN" compare "$OUT/$name/default/lightmap.exr" "$OUT/$name/reference/lightmap.exr" "${args[@]}"
        done
    done
}

measure monkey monkey.glb
measure grey_white_room real/grey_white_room/grey_white_room.gltf --env 1,1,1
measure wooden_staircase real/wooden_staircase/wooden_staircase.gltf
