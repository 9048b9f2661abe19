#!/usr/bin/env bash
# What see-through surfaces cost and change on a real scene: the staircase,
# whose windows are KHR_materials_transmission glass (factor 1), baked as it
# is and with the extension stripped (the glass opaque, as every bake was
# before issue #35), at the same settings. Prints each bake's pass rate and
# the lightmap's mean, and their ratios.
#   bench/see_through_cost.sh [OUT_DIR] [extra bake settings…]
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${LIGHTFARM:-build/client_cli/lightfarm}
SCENE=$(realpath examples/real/wooden_staircase/wooden_staircase.gltf)
OUT=${1:-/tmp/lf-see-through}
shift || true
mkdir -p "$OUT"
# The same file less the extension, in a copy of its folder (a scene names
# its buffers and images by relative paths inside its folder).
rm -rf "$OUT/scene" && cp -r "$(dirname "$SCENE")" "$OUT/scene"
python3 - "$SCENE" "$OUT/scene/opaque_glass.gltf" <<'PY'
import json, sys
doc = json.load(open(sys.argv[1]))
for m in doc.get("materials", []):
    m.get("extensions", {}).pop("KHR_materials_transmission", None)
doc["extensionsUsed"] = [e for e in doc.get("extensionsUsed", []) if e != "KHR_materials_transmission"]
json.dump(doc, open(sys.argv[2], "w"))
PY
for variant in as_is opaque_glass; do
    [ -f "$OUT/$variant/manifest.json" ] && [ -z "${FRESH:-}" ] && continue  # baked before
    scene=$SCENE
    [ "$variant" = opaque_glass ] && scene=$OUT/scene/opaque_glass.gltf
    "$BIN" bake "$scene" --out "$OUT/$variant" --lightmap --res 512 --passes 64 "$@" > /dev/null
done
"$BIN" compare "$OUT/as_is/lightmap.exr" "$OUT/opaque_glass/lightmap.exr" > "$OUT/compare.json"
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
def rate(variant):
    r = json.load(open(f"{out}/{variant}/manifest.json"))["lightmap"]["result"]
    return r["pass"] / r["seconds"]
a, b = rate("as_is"), rate("opaque_glass")
c = json.load(open(f"{out}/compare.json"))
print(f"glass passes light: {a:.2f} passes/s; glass opaque: {b:.2f} passes/s; ratio {a / b:.3f}")
print("the lightmap with the glass passing light against it opaque (lightfarm compare):")
print(json.dumps(c, indent=1))
PY
