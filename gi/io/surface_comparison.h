// Two lightmap bakes of one scene compared where its surfaces are, not texel
// by texel: each bake's lightmap is read (bilinear, as a viewer reads it)
// at the same random points of the surface, each through its own lightmap
// UVs. So bakes with different atlases (another resolution, texel density,
// or chart layout) compare against one reference on an equal footing: the
// error a viewer sees, whatever the texels. Texel-by-texel comparison
// (compare_to_reference) needs one atlas.
#pragma once

#include "io/image_files.h"
#include "scene/scene.h"

#include <cstddef>
#include <cstdint>

namespace lf {

struct SurfacePointOptions {
    size_t points = 200000;  // area-weighted over the surfaces both bakes lightmap
    uint32_t seed = 1;
};

// Over the points and the three channels, as ReferenceError's: rmse,
// relative_rmse (to the reference's mean), bias = mean / reference mean - 1.
struct SurfaceComparison {
    double rmse = 0.0;
    double relative_rmse = 0.0;
    double bias = 0.0;
    double reference_mean = 0.0;
    size_t points = 0;
};

// `bake_scene` and `reference_scene` are the two bakes' scenes with their
// lightmap UVs (uv1, as a bake's scene.lightmapped.glb loads), the same
// triangles in the same order; `bake` and `reference` their one-page
// lightmaps (R, G, B and kCoveredChannel). A lookup reads the covered
// texels among its four taps, and a point whose taps hold none in either
// bake is left out. Triangles without a lightmap in either (no area in its
// UVs) hold no points. Throws std::runtime_error, saying which, where
// the triangles differ or an image lacks a channel.
SurfaceComparison compare_at_surface_points(const Scene& bake_scene, const FloatImage& bake,
                                            const Scene& reference_scene, const FloatImage& reference,
                                            const SurfacePointOptions& options = {});

}  // namespace lf
