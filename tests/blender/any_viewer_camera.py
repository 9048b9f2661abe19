# The camera and render settings of tests/web/any_viewer.mjs's stock
# three.js render, for Blender (render_glb.py and import_bake.py use it):
#  * the camera: the meshes' box from glTF's -z, 40 degrees vertically,
#    square, 1.05 x the distance at which the box fills the frame (glTF is
#    y-up, Blender z-up: the importer maps glTF (x, y, z) to (x, -z, y));
#  * Cycles, one sample at each pixel's centre (a filter of 0.01 px: no
#    anti-aliasing, as three.js renders without it), no world (black, as
#    the three.js page's background);
#  * the "Standard" view transform: an unlit surface's texture (sRGB)
#    comes out as it is stored, as three.js's sRGB output gives it. An
#    OPEN_EXR output is the linear render, before any view transform.
import math
import sys

import bpy
from mathutils import Vector


def to_blender(p):
    return Vector((p.x, -p.z, p.y))


def render_like_any_viewer(out_path, size, file_format="PNG"):
    scene = bpy.context.scene
    # The box in glTF coordinates, as three.js's Box3.setFromObject gives it.
    corners = [obj.matrix_world @ Vector(c) for obj in scene.objects if obj.type == "MESH" for c in obj.bound_box]
    if not corners:
        sys.exit("any_viewer_camera.py: nothing to render: no mesh")
    gltf = [Vector((p.x, p.z, -p.y)) for p in corners]
    lo = Vector((min(p.x for p in gltf), min(p.y for p in gltf), min(p.z for p in gltf)))
    hi = Vector((max(p.x for p in gltf), max(p.y for p in gltf), max(p.z for p in gltf)))
    centre, extent = (lo + hi) / 2, hi - lo
    distance = 0.5 * max(extent.x, extent.y) / math.tan(math.radians(20)) + 0.5 * extent.z
    eye = Vector((centre.x, centre.y, centre.z - 1.05 * distance))

    camera = bpy.data.objects.new("any_viewer_camera", bpy.data.cameras.new("any_viewer_camera"))
    scene.collection.objects.link(camera)
    camera.location = to_blender(eye)
    camera.rotation_euler = (to_blender(centre) - to_blender(eye)).to_track_quat("-Z", "Y").to_euler()
    camera.data.sensor_fit = "VERTICAL"
    camera.data.angle_y = math.radians(40)
    camera.data.clip_start, camera.data.clip_end = 0.01, 100.0
    scene.camera = camera

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.cycles.filter_width = 0.01
    scene.render.resolution_x = scene.render.resolution_y = int(size)
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.dither_intensity = 0.0  # no noise added to the 8-bit output
    scene.render.image_settings.file_format = file_format
    scene.render.image_settings.color_mode = "RGB"
    if file_format == "OPEN_EXR":
        scene.render.image_settings.color_depth = "32"
    scene.render.filepath = out_path
    bpy.ops.render.render(write_still=True)