"""An independent reference: Blender Cycles bakes a glTF scene's lightmap
atlas (TEXCOORD_1) the way examples/SOURCES.md describes its Cornell
box reference, so that other scenes (a variant of the box, a test scene)
can be checked against a second renderer. Run it inside Blender 3.4
(Debian 12's `blender` package):

    blender -b --factory-startup --python bench/cycles_bake.py -- \\
        SCENE.gltf OUT.exr SAMPLES SEED [RES] [direct|indirect|all]

OUT.exr holds RGB = irradiance/pi per texel (Cycles' DIFFUSE bake with
direct and indirect light and no colour), linear, RES x RES (256 by
default), rows from the top as lightfarm writes them. Every material is
rebuilt as a Lambertian diffuse BSDF with albedo = its base colour plus
one-sided emission (Blender's Principled BSDF adds specular and sheen,
which a Lambertian bake must not have); no world light, 32 bounces, no
adaptive sampling, no denoising, the CPU. `direct` bakes the direct light
alone, to compare with a closed form.

Checked against the shipped reference: the Cornell box at 1024 samples,
seed 7, is 2.27% relative RMSE and +0.004% bias from it (SOURCES.md's
table: 2.26% at 1024 samples); the 32768-sample reference itself is the
mean of two such bakes.
"""
import sys

import bpy
import numpy

numpy.bool = bool  # Blender 3.4.1's glTF importer still uses an alias NumPy 1.24 removed

args = sys.argv[sys.argv.index("--") + 1:]
if len(args) < 4:
    sys.exit("usage: blender -b --factory-startup --python cycles_bake.py -- SCENE OUT.exr SAMPLES SEED [RES] "
             "[direct|indirect|all]")
scene_path, out_path, samples, seed = args[0], args[1], int(args[2]), int(args[3])
res = int(args[4]) if len(args) > 4 else 256
light = args[5] if len(args) > 5 else "all"
passes = {"direct": {"DIRECT"}, "indirect": {"INDIRECT"}, "all": {"DIRECT", "INDIRECT"}}[light]

bpy.ops.wm.read_factory_settings(use_empty=True)  # no world: nothing lights the scene but its own emitters
bpy.ops.import_scene.gltf(filepath=scene_path)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
cycles = scene.cycles
cycles.device = "CPU"
cycles.samples = samples
cycles.seed = seed
cycles.use_adaptive_sampling = False
cycles.use_denoising = False
cycles.max_bounces = cycles.diffuse_bounces = 32
cycles.sample_clamp_direct = cycles.sample_clamp_indirect = 0.0

image = bpy.data.images.new("bake", res, res, float_buffer=True, alpha=False)


def lambertian(material):
    """Rebuilds `material` as diffuse + one-sided emission, with the bake's image node active."""
    nodes, links = material.node_tree.nodes, material.node_tree.links
    principled = next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None)
    base = tuple(principled.inputs["Base Color"].default_value) if principled else (0.8, 0.8, 0.8, 1.0)
    emission = tuple(principled.inputs["Emission"].default_value) if principled else (0.0, 0.0, 0.0, 1.0)
    strength = principled.inputs["Emission Strength"].default_value if principled else 1.0
    for n in list(nodes):
        nodes.remove(n)
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = base
    diffuse.inputs["Roughness"].default_value = 0.0  # Lambert, not Oren-Nayar
    emit = nodes.new("ShaderNodeEmission")
    emit.inputs["Color"].default_value = emission
    # One-sided: strength x (1 - backfacing).
    geometry = nodes.new("ShaderNodeNewGeometry")
    front = nodes.new("ShaderNodeMath")
    front.operation = "SUBTRACT"
    front.inputs[0].default_value = 1.0
    links.new(geometry.outputs["Backfacing"], front.inputs[1])
    scaled = nodes.new("ShaderNodeMath")
    scaled.operation = "MULTIPLY"
    scaled.inputs[1].default_value = strength
    links.new(front.outputs[0], scaled.inputs[0])
    links.new(scaled.outputs[0], emit.inputs["Strength"])
    both = nodes.new("ShaderNodeAddShader")
    links.new(diffuse.outputs[0], both.inputs[0])
    links.new(emit.outputs[0], both.inputs[1])
    links.new(both.outputs[0], nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    target = nodes.new("ShaderNodeTexImage")
    target.image = image
    nodes.active = target


for material in bpy.data.materials:
    if material.use_nodes:
        lambertian(material)

bpy.ops.object.select_all(action="DESELECT")
meshes = [o for o in scene.objects if o.type == "MESH"]
for o in meshes:
    if len(o.data.uv_layers) < 2:
        sys.exit(f"{o.name}: no TEXCOORD_1 (the lightmap atlas) to bake into")
    o.data.uv_layers.active = o.data.uv_layers[1]  # TEXCOORD_1
    o.select_set(True)
bpy.context.view_layer.objects.active = meshes[0]
bpy.ops.object.bake(type="DIFFUSE", pass_filter=passes, margin=4, use_clear=True, target="IMAGE_TEXTURES")

# Linear floats: no view transform on the way out.
scene.view_settings.view_transform = "Standard"
scene.display_settings.display_device = "None"
scene.render.image_settings.file_format = "OPEN_EXR"
scene.render.image_settings.color_depth = "32"
scene.render.image_settings.exr_codec = "ZIP"
image.save_render(out_path, scene=scene)
