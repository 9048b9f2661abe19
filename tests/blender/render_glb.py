# blender -b --factory-startup --python tests/blender/render_glb.py -- SCENE.glb OUT.png SIZE
#
# Renders a glb as Blender's own glTF importer sees it (issue #36: the
# any-viewer glb, scene.unlit.glb, in a viewer that knows nothing of
# lightfarm), from the camera tests/web/any_viewer.mjs uses for its stock
# three.js render (any_viewer_camera.py), so the two can be compared pixel
# for pixel. The importer turns KHR_materials_unlit into an emission seen
# by camera rays; the base colour texture on TEXCOORD_1 reads the second
# UV map.
import os
import sys

import bpy
import numpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from any_viewer_camera import render_like_any_viewer  # noqa: E402

# Debian 12's Blender 3.4.1 importer asks numpy for np.bool, an alias that
# Debian 12's numpy 1.24 no longer has (it was the builtin bool).
if not hasattr(numpy, "bool"):
    numpy.bool = bool

glb, out_png, size = sys.argv[sys.argv.index("--") + 1:][:3]

bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=glb)
render_like_any_viewer(out_png, int(size))
