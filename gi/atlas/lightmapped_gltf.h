// scene.lightmapped.glb: the input glTF with the generated lightmap UVs added
// as TEXCOORD_1 (DESIGN.md "Outputs"), so an engine can apply the lightmap.
#pragma once

#include "lightmap_rgbm.h"
#include "atlas/texel_samples.h"
#include "scene/scene.h"

#include <filesystem>
#include <string>
#include <vector>

namespace lf {

// Re-reads `source_gltf` (the file `scene` was loaded from, already
// validated by lf::load_scene) and writes `out_glb`: every primitive that
// `scene` instances gets TEXCOORD_1 from Scene::uv1. Where the atlas split
// vertices (Scene::source_vertex), the primitive gets new vertex attributes
// (every attribute and morph target gathered through source_vertex, so
// positions are bit-for-bit the originals) and a new TRIANGLES index buffer.
// A mesh placed by several nodes is copied for each extra node, since each
// placement has its own atlas region. Buffers are merged into the GLB's
// binary chunk and external images embedded. The write is atomic (temporary
// file in the same directory, then rename). Throws std::runtime_error.
// With `lights_baked` (the job's lightmap holds the punctual lights' direct
// light), the file's KHR_lights_punctual lights leave it, named in the
// asset's extras ("lightfarm_baked_lights"): a light counts once.
void write_lightmapped_glb(const std::filesystem::path& source_gltf, const Scene& scene,
                           const std::filesystem::path& out_glb, bool lights_baked);

// An 8-bit grey map (rows from the top), e.g. ambient occlusion.
struct GreyImage {
    int width = 0;
    int height = 0;
    std::vector<uint8_t> values;  // width * height, linear
};

// The baked maps scene.lit.glb carries; each is optional.
struct LitSceneMaps {
    // The final lightmap, RGBM-encoded: embedded as a PNG and applied to every
    // material of the baked primitives with the MOZ_lightmap extension
    // (texCoord 1), the convention three.js-based viewers read:
    //   "MOZ_lightmap": {"index": T, "texCoord": 1, "intensity": pi,
    //                    "extras": {"encoding": "RGBM", "rgbm_range": R}}
    // A viewer shows irradiance E = intensity * R * rgb * a, as three.js's
    // lightMap expects (the texels are E/pi, DESIGN.md "Units").
    const protocol::RgbmImage* lightmap = nullptr;
    // Ambient occlusion: every baked material's core glTF occlusionTexture
    // (texCoord 1, strength 1; an occlusion texture of the file's own is
    // replaced), as a PNG whose R = G = B = the occlusion.
    const GreyImage* occlusion = nullptr;
};

// scene.lit.glb: write_lightmapped_glb's file with `maps` embedded (the
// punctual lights dropped when `maps` has a lightmap).
// Primitives without a material get a white, rough, non-metallic one to
// carry them.
void write_lit_glb(const std::filesystem::path& source_gltf, const Scene& scene, const LitSceneMaps& maps,
                   const std::filesystem::path& out_glb);

// An sRGB image, 8 bits per channel.
struct ColourImage {
    int width = 0;
    int height = 0;
    std::vector<uint8_t> rgb;  // width * height * 3, rows from the top
};

// The light leaving each texel as lightfarm's own 3D view shows it, for
// scene.unlit.glb: emission + albedo x E/pi, E/pi from `lightmap_rgb`
// (interleaved RGB of the atlas's size; the texel's albedo and emission
// averaged over its sample points, as the bake averages them), at the
// view's automatic exposure of the lightmap (as the server's
// X-Lightfarm-Exposure) through its filmic curve, sRGB
// (protocol/display_tone.h); the charts dilated as the lightmap is.
ColourImage unlit_look(const TexelSamples& texels, const std::vector<float>& lightmap_rgb);

// scene.unlit.glb: write_lightmapped_glb's file for any glTF viewer, its look
// baked in: every material gets KHR_materials_unlit with `look` (on
// TEXCOORD_1) as its base colour texture, white base colour factor (alpha
// kept), and none of its own textures or emission. Unlit because a viewer
// then adds no light of its own (an emissive texture over a black base
// colour still takes the viewer's environment reflections), and because
// the stock viewers read the extension: three.js's GLTFLoader (a
// MeshBasicMaterial), Blender's importer, Babylon.js, model-viewer; one
// that does not shows the texture as a lit base colour. Alpha cut-outs
// from a base colour texture are lost (the look is RGB at the lightmap's
// resolution).
void write_unlit_glb(const std::filesystem::path& source_gltf, const Scene& scene, const ColourImage& look,
                     const std::filesystem::path& out_glb);

// One float vertex attribute for one primitive instance: `components` (1..4)
// values per vertex of the instance, Scene vertex first_vertex + k at k.
struct VertexAttribute {
    std::string name;  // "TEXCOORD_1", "_SH_TRANSFER_0", "COLOR_0" …
    int components = 4;
    std::vector<float> values;
};

// The general form of write_lightmapped_glb: re-reads `source_gltf` and
// writes `out_glb` with per_instance[i]'s attributes added to (or replacing
// those of the same name on) the primitive of scene.instances[i], with the
// same vertex splitting, mesh copying per node, buffer merging, image
// embedding and atomic write. unlit_materials adds KHR_materials_unlit to
// every material (for baked vertex colours). Throws std::runtime_error.
void write_glb_with_vertex_attributes(const std::filesystem::path& source_gltf, const Scene& scene,
                                      const std::vector<std::vector<VertexAttribute>>& per_instance,
                                      const std::filesystem::path& out_glb, bool unlit_materials = false);

}  // namespace lf
