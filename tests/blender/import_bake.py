# blender -b --factory-startup --python tests/blender/import_bake.py -- BAKE_DIR OUT.exr SIZE
# blender -b --factory-startup --python tests/blender/import_bake.py -- --send URL TOKEN SCENE.glb BAKE_DIR OUT.exr SIZE
#
# The add-on (blender/lightfarm_blender) as a user drives it, headless:
# imports the bake in BAKE_DIR, or first opens SCENE.glb as the open scene,
# sends it to the lightfarmd at URL and imports what comes back into
# BAKE_DIR; then renders with tests/web/any_viewer.mjs's camera
# (any_viewer_camera.py) into OUT.exr, linear, for tests/test_viewers.cpp
# to put through lightfarm's own tone curve and compare with its view.
# Prints one JSON line: what was imported.
import json
import os
import sys

import bpy

here = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, here)
sys.path.insert(0, os.path.join(here, "..", "..", "blender"))
import lightfarm_blender  # noqa: E402
from any_viewer_camera import render_like_any_viewer  # noqa: E402
from lightfarm_blender import bake_import  # noqa: E402

args = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
lightfarm_blender.register()  # as Blender does for an enabled add-on
job = None
try:
    if args[0] == "--send":
        url, token, scene_glb, folder, out_exr, size = args[1:7]
        bake_import._numpy_bool_alias()
        bpy.ops.import_scene.gltf(filepath=scene_glb)
        job = lightfarm_blender.send_open_scene(url, token, {"outputs": {"lightmap": {"passes": 8}}, "atlas": {"res": 128}})
        lightfarm_blender.receive_bake(url, token, job, folder)
        # The bake replaces the scene that was sent.
        for obj in list(bpy.data.objects):
            bpy.data.objects.remove(obj)
        objects = bake_import.import_bake(folder)
    else:
        # The menu's operator, as File > Import > lightfarm bake runs it.
        folder, out_exr, size = args[:3]
        bpy.ops.lightfarm.import_bake(filepath=os.path.join(folder, "scene.lightmapped.glb"))
        objects = [o for o in bpy.data.objects if o.type == "MESH"]
except Exception as e:  # one line for the test's log
    print(json.dumps({"error": "%s: %s" % (type(e).__name__, e)}))
    sys.exit(1)
looks = sorted({m.name for o in objects for m in o.data.materials if m and m.get("lightfarm_baked_look")})
render_like_any_viewer(out_exr, int(size), "OPEN_EXR")
print(json.dumps({"job": job, "objects": len(objects), "baked_looks": len(looks),
                  "images": sorted(i.name for i in bpy.data.images)}))
