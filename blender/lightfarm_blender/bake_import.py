# Importing a lightfarm bake into Blender: scene.lightmapped.glb, with each
# material showing the baked light (docs/engines.md "Blender").
#
# A lightmap texel holds irradiance / pi in linear RGB (DESIGN.md): the
# radiance a white Lambertian surface reflects. So a Lambertian surface's
# baked look is base colour x lightmap, plus its own emission, which the
# lightmap does not hold. Each material gets that as an Emission shader (a
# render shows the bake, whatever lights the file had: a bake's glbs carry
# none, README "Outputs"), its Principled BSDF kept beside it, unlinked,
# for a user who wants it back. The lightmap is read on the second UV map:
# Blender's glTF importer names TEXCOORD_1 "UVMap.001".
#
# Pages. A bake whose atlas took several pages writes lightmap.page-N.exr,
# and each glTF primitive lies on one page. Blender's importer joins a
# mesh's primitives into one mesh, in their order, and drops their extras,
# so lightfarm writes each mesh's pages and triangle counts into the mesh's
# own extras (lightfarm_lightmap_pages, lightfarm_primitive_triangles; -1:
# no lightmap), which the importer keeps as custom properties: each
# polygon's page follows, and a material used on several pages gets one
# copy per page.
import os

import bpy

LIGHTMAP_UV = "UVMap.001"  # glTF TEXCOORD_1, as Blender's importer names it
PAGES_KEY = "lightfarm_lightmap_pages"
TRIANGLES_KEY = "lightfarm_primitive_triangles"


class BakeImportError(Exception):
    """A bake folder that cannot be imported; the message names the file."""


def _numpy_bool_alias():
    # Debian 12's Blender 3.4 importer asks numpy for np.bool, an alias that
    # Debian 12's numpy 1.24 no longer has (it was the builtin bool).
    import numpy

    if not hasattr(numpy, "bool"):
        numpy.bool = bool


def lightmap_files(folder):
    """The lightmap image of each page, page 0 first."""
    pages = []
    while os.path.exists(os.path.join(folder, "lightmap.page-%d.exr" % len(pages))):
        pages.append(os.path.join(folder, "lightmap.page-%d.exr" % len(pages)))
    if pages:
        return pages
    single = os.path.join(folder, "lightmap.exr")
    if not os.path.exists(single):
        raise BakeImportError(folder + ": no lightmap.exr (a bake with a lightmap writes it)")
    return [single]


def _load_image(path):
    image = bpy.data.images.load(path, check_existing=True)
    # The texels are linear light: no colour transform on the way in.
    image.colorspace_settings.name = "Non-Color"
    return image


def _source_of(socket):
    """What feeds an input: the linked output socket, or None and its value."""
    if socket.is_linked:
        return socket.links[0].from_socket, None
    return None, socket.default_value


def wire_baked_look(material, image):
    """Makes `material` show base colour x lightmap + emission (Emission shader)."""
    material.use_nodes = True
    nt = material.node_tree
    nodes, links = nt.nodes, nt.links
    output = next((n for n in nodes if n.type == "OUTPUT_MATERIAL" and n.is_active_output), None)
    if output is None:
        output = nodes.new("ShaderNodeOutputMaterial")
    bsdf = next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None)

    uv = nodes.new("ShaderNodeUVMap")
    uv.uv_map = LIGHTMAP_UV
    lightmap = nodes.new("ShaderNodeTexImage")
    lightmap.image = image
    lightmap.interpolation = "Linear"
    lightmap.extension = "EXTEND"  # charts are padded; nothing beyond the page
    lightmap.label = "lightfarm lightmap"
    links.new(uv.outputs["UV"], lightmap.inputs["Vector"])

    lit = nodes.new("ShaderNodeVectorMath")
    lit.operation = "MULTIPLY"
    links.new(lightmap.outputs["Color"], lit.inputs[1])
    base, value = _source_of(bsdf.inputs["Base Color"]) if bsdf else (None, (1.0, 1.0, 1.0, 1.0))
    if base is not None:
        links.new(base, lit.inputs[0])
    else:
        lit.inputs[0].default_value = value[:3]

    colour = lit.outputs["Vector"]
    if bsdf is not None:
        glow, glow_value = _source_of(bsdf.inputs["Emission"])
        strength = bsdf.inputs["Emission Strength"].default_value
        if glow is not None or any(c > 0.0 for c in glow_value[:3]):
            scaled = nodes.new("ShaderNodeVectorMath")
            scaled.operation = "SCALE"
            scaled.inputs["Scale"].default_value = strength
            if glow is not None:
                links.new(glow, scaled.inputs[0])
            else:
                scaled.inputs[0].default_value = glow_value[:3]
            total = nodes.new("ShaderNodeVectorMath")
            total.operation = "ADD"
            links.new(colour, total.inputs[0])
            links.new(scaled.outputs["Vector"], total.inputs[1])
            colour = total.outputs["Vector"]

    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0
    links.new(colour, emission.inputs["Color"])
    surface = emission.outputs["Emission"]
    # Cut-outs and blends keep their alpha.
    if bsdf is not None and material.blend_method != "OPAQUE":
        alpha, alpha_value = _source_of(bsdf.inputs["Alpha"])
        mix = nodes.new("ShaderNodeMixShader")
        clear = nodes.new("ShaderNodeBsdfTransparent")
        if alpha is not None:
            links.new(alpha, mix.inputs["Fac"])
        else:
            mix.inputs["Fac"].default_value = alpha_value
        links.new(clear.outputs["BSDF"], mix.inputs[1])
        links.new(surface, mix.inputs[2])
        surface = mix.outputs["Shader"]
    links.new(surface, output.inputs["Surface"])
    material["lightfarm_baked_look"] = True


def _default_material():
    # glTF's default material: base colour 1, no emission.
    material = bpy.data.materials.new("lightfarm default")
    material.use_nodes = True
    bsdf = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    return material


def _polygon_pages(mesh, single_page):
    """Each polygon's page, from the mesh's extras (see the top)."""
    pages, triangles = mesh.get(PAGES_KEY), mesh.get(TRIANGLES_KEY)
    if pages is None or triangles is None:
        if not single_page:
            raise BakeImportError(
                "mesh " + mesh.name + " does not say its lightmap pages (" + PAGES_KEY + "): "
                "bake it again with this lightfarm"
            )
        return [0] * len(mesh.polygons)
    per_polygon = []
    for page, count in zip(list(pages), list(triangles)):
        per_polygon += [int(page)] * int(count)
    if len(per_polygon) != len(mesh.polygons):
        raise BakeImportError(
            "mesh %s: %d polygons, its primitives have %d triangles" % (mesh.name, len(mesh.polygons), len(per_polygon))
        )
    return per_polygon


def import_bake(folder):
    """Imports the bake in `folder`: returns the mesh objects imported."""
    glb = os.path.join(folder, "scene.lightmapped.glb")
    if not os.path.exists(glb):
        raise BakeImportError(folder + ": no scene.lightmapped.glb (a bake with a lightmap writes it)")
    images = [_load_image(path) for path in lightmap_files(folder)]
    _numpy_bool_alias()
    before = set(bpy.data.objects)
    result = bpy.ops.import_scene.gltf(filepath=glb)
    if "FINISHED" not in result:
        raise BakeImportError(glb + ": Blender's glTF importer failed")
    objects = [o for o in bpy.data.objects if o not in before and o.type == "MESH"]

    looks = {}  # (material name, page) -> its baked-look material

    def look(material, page):
        key = (material.name, page)
        if key not in looks:
            copy = material.copy()
            copy.name = "%s (lightmap page %d)" % (material.name, page) if len(images) > 1 else material.name + " (baked)"
            wire_baked_look(copy, images[page])
            looks[key] = copy
        return looks[key]

    default = None
    done = set()
    for obj in objects:
        mesh = obj.data
        if mesh.name in done:
            continue
        done.add(mesh.name)
        if not mesh.materials:
            default = default or _default_material()
            mesh.materials.append(default)
        pages = _polygon_pages(mesh, len(images) == 1)
        slots = list(mesh.materials)
        indices = [0] * len(mesh.polygons)
        mesh.polygons.foreach_get("material_index", indices)
        new_slot = {}  # (slot, page) -> slot of its baked look
        for p, (slot, page) in enumerate(zip(indices, pages)):
            if page < 0 or slots[slot] is None:
                continue  # no lightmap here: the material stays as it was
            if page >= len(images):
                raise BakeImportError("mesh %s: page %d, the bake has %d" % (mesh.name, page, len(images)))
            key = (slot, page)
            if key not in new_slot:
                mesh.materials.append(look(slots[slot], page))
                new_slot[key] = len(mesh.materials) - 1
            indices[p] = new_slot[key]
        mesh.polygons.foreach_set("material_index", indices)
        mesh.update()
    return objects
