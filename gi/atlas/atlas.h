// The lightmap atlas: where every triangle's lightmap texels are.
//
// Image space follows DESIGN.md: glTF UV (u,v) maps to pixel (u·W, v·H) from
// the top-left corner; texel (x, y) covers [x, x+1) x [y, y+1), centre at
// half-integers. A scene whose every primitive has TEXCOORD_1 keeps it
// (use_existing_lightmap_uvs); otherwise generate_lightmap_uvs builds one:
//
//   1. charts: connected triangles (edges matched by position, so split glTF
//      vertices and separate meshes that touch still connect) whose normals are
//      within `max_chart_angle_degrees` of the chart's first (largest)
//      triangle and whose projections onto that triangle's plane do not
//      overlap each other;
//   2. each chart projected to that plane, turned to its minimum-area
//      bounding rectangle, and scaled so its UV area is exactly its world area
//      x density² (one texel density for the whole scene);
//   3. charts packed by texel shape: each rasterized to the texels its
//      triangles touch (at the density and the sub-texel offset it gets),
//      and placed, tallest first, in a bitmap of the atlas at the lowest
//      (then leftmost) place where it keeps `padding` empty texels to every
//      other chart, so bilinear lookups and dilation never mix charts; turned
//      by 180° (and 90°, 270° for larger charts) where that places it lower,
//      so charts nest and small ones fill the gaps beside large ones; if they
//      do not fit, the density shrinks;
//      with pages (AtlasOptions::max_pages), each chart goes on the first
//      page where it fits, a new page opened where none holds it;
//   4. vertices on chart borders split (one copy per chart), UV1 written.
#pragma once

#include "scene/scene.h"

#include <cstddef>
#include <cstdint>
#include <functional>
#include <stdexcept>
#include <vector>

namespace lf {

// The atlas side when neither a resolution nor a texel density is asked for.
constexpr int kDefaultAtlasResolution = 256;

struct AtlasOptions {
    int resolution = 0;          // square atlas side in texels; 0 = derive from texel_density
    float texel_density = 0.0f;  // texels per metre; 0 = derive from resolution
                                 // (both 0: kDefaultAtlasResolution; both set: density shrinks if it does not fit)
    int padding = 2;             // empty texels between any two charts
    float max_chart_angle_degrees = 40.0f;  // how far a chart's normals may turn from its first triangle's
    int max_resolution = 8192;              // a density-derived atlas is never larger; the density shrinks instead
    // With neither resolution nor texel_density: the density at which at most
    // this fraction of the surface lies within half a texel of a chart
    // border (AtlasReport::border_fraction), the map's resolution bias being
    // proportional to it (docs/BENCHMARKS.md, "Resolution from the scene").
    // The atlas then stays within auto_max_resolution, its density shrinking.
    // 0: kDefaultAtlasResolution.
    float max_border_fraction = 0.0f;
    int auto_max_resolution = 4096;
    // Pages: where an asked texel_density does not fit one page (of
    // `resolution`, else max_resolution), or the charts do not fit it even at
    // one texel each, they are packed on up to this many pages of that side
    // (LightmapPages) rather than the density shrinking; more than this, and
    // the density shrinks until they fit. 1: one page, as before.
    int max_pages = 1;
    // Generated atlases: called once the charts are made, with each
    // triangle's chart (ids below chart_count); returns 1 for each chart no
    // light can reach (gi/bake/unlit_charts.h). Those are packed at
    // kUnlitChartScale of their size, and left out of the border fraction.
    std::function<std::vector<uint8_t>(const std::vector<uint32_t>& triangle_chart, size_t chart_count)>
        find_unlit_charts = nullptr;
    // Generated atlases (atlas.light_density): called after find_unlit_charts
    // with the charts it flagged and `texel`, about the world size of a
    // texel at the density the scene gets otherwise; returns each chart's
    // density over the scene's (gi/bake/light_density.h; 1 for the flagged
    // ones), whose sum of area x scale^2 is the charts' area: as many texels.
    std::function<std::vector<double>(const std::vector<uint32_t>& triangle_chart, size_t chart_count,
                                      const std::vector<uint8_t>& flagged, double texel)>
        light_scales = nullptr;
};

// A chart no light reaches holds one value (black): 1/8 of the density, 1/64 of the texels.
constexpr double kUnlitChartScale = 0.125;
// A chart of a mesh without a lightmap (PrimitiveInstance::lightmap_scale 0)
// gets one texel (chart_rect rounds up), which holds its samples' mean; no
// gather reads it (a ray that lands on such a mesh gathers on from there).
constexpr double kUnmappedChartScale = 1e-9;

struct AtlasReport {
    int width = 0;
    int height = 0;                        // with pages: all of them stacked, each width x width
    LightmapPages pages;                   // as Scene::lightmap_pages
    float texel_density = 0.0f;            // texels per metre (for existing or baseline UVs: the average)
    size_t charts = 0;                     // charts (existing UVs: islands of triangles sharing vertices)
    double utilisation = 0.0;              // texels touched by some triangle / all texels
    bool generated = false;                // this call wrote Scene::uv1
    std::vector<uint32_t> triangle_chart;  // chart of every triangle (generated atlases only)
    // The fraction of the surface within half a texel of a chart border,
    // border length / (2 x area x texel_density): where texels straddle a
    // crease or a chart's edge and lookups blend across it.
    double border_fraction = 0.0;
    bool density_from_scene = false;   // chosen for max_border_fraction
    size_t unlit_charts = 0;           // packed at kUnlitChartScale (AtlasOptions::find_unlit_charts)
    size_t mesh_scaled_charts = 0;     // packed at their mesh's PrimitiveInstance::lightmap_scale (not 1)
    size_t unmapped_charts = 0;        // of meshes without a lightmap (lightmap_scale 0): one texel each
    double unlit_area_fraction = 0.0;  // their share of the surface
    size_t light_scaled_charts = 0;    // packed at a density of their light's (AtlasOptions::light_scales), not 1
};

// Builds charts, packs them, splits vertices on chart borders and writes
// Scene::uv1, Scene::source_vertex and PrimitiveInstance::has_uv1 for every
// instance (each instance's vertices stay one contiguous range). Throws
// std::runtime_error when even the smallest charts cannot fit the resolution.
AtlasReport generate_lightmap_uvs(Scene& scene, const AtlasOptions& options);

// The atlas size and texel density for a scene that keeps its TEXCOORD_1:
// resolution as given (it wins when both are set: the file fixes the ratio),
// or derived from the density and the ratio of the UV-mapped area to the
// world area (capped at max_resolution), or kDefaultAtlasResolution when neither is set.
AtlasReport use_existing_lightmap_uvs(const Scene& scene, const AtlasOptions& options);

// The charts do not fit the atlas's resolution (or max_resolution) even at
// one texel each: what prepare_lightmap_atlas throws for a resolution that
// is too small, apart from every other failure.
struct AtlasDoesNotFit : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// The smallest square side that a generated atlas of `scene` fits in at one
// texel per chart (with options.padding): smaller resolutions fail with
// "charts do not fit". 0 when even options.max_resolution is too small.
// Builds the charts (about a second for 260k triangles), then packs a few
// times, up from a lower bound on the side (the charts' padded texels).
int smallest_atlas_resolution(const Scene& scene, const AtlasOptions& options = {});

// Islands of triangles connected through shared vertex indices, per
// triangle (the island's id is one of its vertices). These are the lightmap's
// charts: a generated atlas splits vertices on chart borders, and a glTF
// exporter splits them on UV seams.
std::vector<uint32_t> uv_island_of_triangle(const Scene& scene);

// TEXCOORD_1 when every primitive has it, else a generated atlas.
AtlasReport prepare_lightmap_atlas(Scene& scene, const AtlasOptions& options);

// The baseline: the thesis's triangle-pair atlas (Moreno-Fortuny 2005, §4.2 and
// Appendix C.1). Neighbouring triangles are paired, pairs sorted by area, and
// the texture recursively halved along its longer axis (balancing 1.5 x
// triangle share + area share) until each pair has a cell; each pair fills its
// cell as two right triangles, inset by half a texel (Carr and Hart). For
// comparisons only: it distorts triangles and cuts a seam around every pair.
AtlasReport generate_triangle_pair_uvs(Scene& scene, const AtlasOptions& options);

}  // namespace lf
