#!/usr/bin/env bash
# Tracer throughput on the benchmark scenes, one JSON line per scene
# (lightfarm raybench), then a markdown table row per scene.
#   bench/raybench.sh [--device auto|gpu|cpu] [--seconds S]
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
scenes="${LIGHTFARM_SCENES:-$root/examples}"
lightfarm="$root/build/client_cli/lightfarm"
for scene in cornell_box.gltf monkey.glb spheres.glb real/wooden_staircase/wooden_staircase.gltf; do
  "$lightfarm" raybench "$scenes/$scene" "$@" | python3 -c '
import json, sys
r = json.load(sys.stdin)
b = r["bvh"]
print(json.dumps(r), file=sys.stderr)
print("| %s | %d | %s | %.3g | %.3g | %.3f s | %.1f MiB | %d |" % (
    r["scene"].split("/")[-1], r["triangles"], r["device"]["renderer"],
    r["incoherent"]["rays_per_second"] / 1e6, r["coherent"]["rays_per_second"] / 1e6,
    b["build_seconds"], b["bytes"] / 2**20, b["max_depth"]))'
done
