// The Scene: only what a bake needs, in world space (DESIGN.md "Data flow").
//
// Units: metres; radiance W/(sr·m²), linear RGB. Every primitive of every node
// instance is flattened into shared vertex/triangle arrays; `instances` maps
// the flattened ranges back to glTF nodes, meshes, primitives and vertices so
// writers can add attributes (TEXCOORD_1, SH transfer) to the original file.
#pragma once

#include <glm/glm.hpp>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace lf {

struct Bounds {
    glm::vec3 lo{std::numeric_limits<float>::max()};
    glm::vec3 hi{-std::numeric_limits<float>::max()};
    void extend(const glm::vec3& p) {
        lo = glm::min(lo, p);
        hi = glm::max(hi, p);
    }
    void extend(const Bounds& b) {
        lo = glm::min(lo, b.lo);
        hi = glm::max(hi, b.hi);
    }
    bool empty() const { return lo.x > hi.x; }
    glm::vec3 centre() const { return 0.5f * (lo + hi); }
    glm::vec3 extent() const { return empty() ? glm::vec3(0.0f) : hi - lo; }
    float surface_area() const {
        glm::vec3 d = extent();
        return 2.0f * (d.x * d.y + d.y * d.z + d.z * d.x);
    }
};

// A decoded texture in linear RGBA float (sRGB already decoded for colour
// textures), row 0 at the top as in the image file.
struct Texture {
    std::string name;
    int width = 0;
    int height = 0;
    std::vector<glm::vec4> texels;  // empty when loaded with LoadLimits::decode_images = false
    glm::vec4 fetch(int x, int y) const { return texels[size_t(y) * size_t(width) + size_t(x)]; }
    // Bilinear lookup with glTF's default REPEAT wrapping; uv (0,0) is the top-left corner.
    glm::vec4 sample(glm::vec2 uv) const;
};

struct Material {
    std::string name;
    glm::vec4 base_color{1.0f};   // linear, multiplied by the texture
    int base_color_texture = -1;  // index into Scene::textures, sampled with TEXCOORD_0
    // Emitted radiance in W/(sr·m²): emissiveFactor x KHR_materials_emissive_strength.
    glm::vec3 emission{0.0f};
    int emissive_texture = -1;  // index into Scene::textures, sampled with TEXCOORD_0
    bool double_sided = false;  // emits (and receives) on both sides
    // How much of the surface is there (glTF alphaMode, with base_color.a
    // times the texture's alpha): all of it (Opaque), where alpha >=
    // alpha_cutoff (Mask: a cut-out), or the fraction alpha (Blend).
    enum class AlphaMode { Opaque, Mask, Blend };
    AlphaMode alpha_mode = AlphaMode::Opaque;
    float alpha_cutoff = 0.5f;
    // KHR_materials_transmission's transmissionFactor: of the light that
    // meets the surface, the fraction that passes through, tinted by the base
    // colour. Straight through: no refraction, no Fresnel reflection, as a
    // lightmapper reads a window.
    float transmission = 0.0f;
    // KHR_materials_volume: the mesh bounds a medium that absorbs, per
    // channel, attenuation per metre of path inside it (Beer-Lambert,
    // -ln(attenuationColor) / attenuationDistance): a ray crossing a closed
    // glass slab of thickness d at angle theta keeps exp(-attenuation d /
    // cos theta). The tracer applies it between where a ray enters the mesh
    // (a front face) and where it leaves (a back face) or ends
    // (trace.glsl's lf_cross_medium). 0 for a thin-walled surface
    // (thicknessFactor 0), which absorbs nothing, and without transmission.
    glm::vec3 attenuation{0.0f};
    // thicknessFactor: the path inside that each crossing of the surface is
    // taken to have where the material's triangles do not close around a
    // volume (Scene::closed_volumes; an open sheet: the glTF spec's
    // approximation for rasterizers).
    float thickness = 0.0f;
    bool has_volume() const { return transmission > 0.0f && attenuation != glm::vec3(0.0f); }
    bool is_emissive() const { return emission.x > 0.0f || emission.y > 0.0f || emission.z > 0.0f; }
    // Light may pass through some of it: the tracer tests its rays' hits.
    bool is_see_through() const { return alpha_mode != AlphaMode::Opaque || transmission > 0.0f; }
};

// KHR_lights_punctual, read radiometrically (DESIGN.md "Conventions").
struct PunctualLight {
    enum class Type { Point, Spot, Directional };
    Type type = Type::Point;
    std::string name;
    glm::vec3 position{0.0f};                // world space (point, spot)
    glm::vec3 direction{0.0f, 0.0f, -1.0f};  // world space, the way light travels (spot, directional)
    // Point/spot: radiant intensity in W/sr; directional: irradiance in W/m².
    glm::vec3 intensity{0.0f};
    float range = 0.0f;               // 0 = infinite
    float inner_cone = 0.0f;          // radians (spot)
    float outer_cone = 0.785398163f;  // radians (spot), glTF default pi/4
};

// One glTF primitive as placed by one node: its slice of the flattened arrays.
struct PrimitiveInstance {
    int node = -1;
    int mesh = -1;
    int primitive = -1;
    uint32_t first_vertex = 0;  // into Scene::positions etc.
    uint32_t vertex_count = 0;  // vertex k of the glTF primitive is first_vertex + k (see Scene::source_vertex once an
                                // atlas split vertices)
    uint32_t first_triangle = 0;  // into Scene::triangles
    uint32_t triangle_count = 0;
    bool has_uv1 = false;   // the glTF primitive had TEXCOORD_1
    bool mirrored = false;  // the node transform has negative determinant
    // Its charts' texel density over the atlas's: a node's (else its mesh's)
    // extras {"lightfarm_lightmap_scale": S}, 0 <= S <= 64 (a hero prop gets
    // more texels, a distant wall fewer), for generated atlases; and
    // 0: no lightmap of its own, in an atlas of any kind: it still casts
    // and bounces light (rays that land on it gather there), and the files
    // give it no lightmap (a prop lit at run time, by probes).
    float lightmap_scale = 1.0f;
    bool has_lightmap() const { return lightmap_scale > 0.0f; }
};

// The lightmap's pages. A generated atlas whose charts do not fit one page
// (at the asked texel density) holds several, each `rows` x `rows` texels:
// the bake sees them stacked top to bottom, `gap` empty rows apart (no
// lookup blends two pages), and uv1 spans the whole stack; the files split
// it again (one image per page, each primitive on its page's UVs).
struct LightmapPages {
    int count = 1;
    int rows = 0;  // a page's side (a generated atlas's; 0 for a file's own UVs: one page, the atlas)
    int gap = 0;
    int stride() const { return rows + gap; }
    int total_rows() const { return count * rows + (count - 1) * gap; }
    // The page that the stacked atlas's v (uv1.y) lies on (inside a chart:
    // a chart's edge may lie on a page's), and v on page `page`.
    int page_of(float v) const {
        return count == 1 ? 0 : std::clamp(int(double(v) * total_rows() / stride()), 0, count - 1);
    }
    float v_on_page(float v, int page) const {
        return count == 1 ? v : float((double(v) * total_rows() - double(page) * stride()) / rows);
    }
};

struct Scene {
    std::string source;  // file the scene was loaded from, for messages

    // Per-vertex, world space.
    std::vector<glm::vec3> positions;
    std::vector<glm::vec3> normals;  // unit length; area-weighted when the file had none
    std::vector<glm::vec2> uv0;      // TEXCOORD_0, or zero
    std::vector<glm::vec2> uv1;      // TEXCOORD_1 (lightmap UVs), or zero
    LightmapPages lightmap_pages;    // the pages uv1 spans (one unless a generated atlas needed more)
    // Per-vertex: the index of the vertex within its glTF primitive. Empty
    // means identity (vertex v of instance i is glTF vertex v - first_vertex).
    // A generated atlas splits vertices that lie on a chart border into one
    // copy per chart; the copies stay inside their instance's range and map
    // back to the glTF vertex they were copied from.
    std::vector<uint32_t> source_vertex;

    // Per-triangle: vertex indices (counter-clockwise = front, mirroring
    // already undone) and material index.
    std::vector<glm::uvec3> triangles;
    std::vector<uint32_t> triangle_material;
    // Empty, or 1 where the bake turned a double-sided triangle round to face
    // the scene (lf::face_double_sided_charts_to_the_scene); files written
    // from the scene keep the input's own winding.
    std::vector<uint8_t> triangle_turned;

    std::vector<PrimitiveInstance> instances;
    std::vector<Material> materials;  // glTF materials, plus a default at the end if any primitive had none
    std::vector<Texture> textures;    // decoded, indexed by materials
    std::vector<PunctualLight> lights;
    // Probe reference points the file names: the world positions of nodes
    // whose extras hold {"lightfarm_probe": true}.
    std::vector<glm::vec3> probe_points;

    Bounds bounds;
    // A hash of the bytes the scene was loaded from (the file and every
    // buffer and image it names): two loads bake the same exactly when equal.
    uint64_t content_hash = 0;
    // Things the user should know that do not make the file invalid
    // ("no light source", "no geometry with area", ignored extensions).
    std::vector<std::string> warnings;

    size_t triangle_count() const { return triangles.size(); }
    bool all_have_lightmap_uvs() const;
    size_t emissive_triangle_count() const;
    // Each triangle's PrimitiveInstance::lightmap_scale (0: no lightmap).
    std::vector<float> triangle_lightmap_scales() const;
    // 1 for each triangle of a mesh without a lightmap (lightmap_scale 0):
    // it casts and bounces light but gets no texels of its own.
    std::vector<uint8_t> triangles_without_lightmap() const;
    // Area of triangle t (world space).
    float triangle_area(size_t t) const;
    glm::vec3 geometric_normal(size_t t) const;  // unit; zero for a degenerate triangle
    // Albedo and emission of triangle t at barycentrics (b1, b2), textures included.
    glm::vec3 albedo_at(size_t t, glm::vec2 bary) const;
    glm::vec3 emission_at(size_t t, glm::vec2 bary) const;
    // The share of the light arriving at triangle t at (b1, b2) that passes
    // through it, per channel: 1 - coverage + coverage x transmission x
    // (base colour x texture), where coverage is how much of the surface is
    // there (Material::alpha_mode). 0 for an opaque surface. A volume's
    // absorption is the path's, not the surface's (Material::attenuation).
    glm::vec3 transmittance_at(size_t t, glm::vec2 bary) const;
    // Per material: whether it bounds a volume that the tracer can follow
    // (Material::attenuation), i.e. it has one and its triangles close around
    // it with one orientation: each edge (vertices welded by position,
    // scene/weld.h) met once in each direction.
    std::vector<bool> closed_volumes() const;
    // Their means over triangle t (textures averaged by the midpoint rule on
    // 16 equal sub-triangles; exact without a texture): what one constant per
    // triangle should be, where one texture sample at the centroid could be
    // any plank of a wooden floor.
    glm::vec3 mean_albedo(size_t t) const;
    glm::vec3 mean_emission(size_t t) const;
};

}  // namespace lf
