// What the lightmap tests share: a bake of a scene built in code; its
// direct light is known by the form factors of form_factors.h.
#pragma once

#include "form_factors.h"
#include "gpu_fixture.h"

#include "atlas/texel_samples.h"
#include "bake/radiosity_map_baker.h"
#include "io/image_files.h"
#include "scene/scene.h"
#include "trace/tracer.h"

#include <glm/glm.hpp>

#include <algorithm>
#include <cmath>

namespace lf::test {

// Lays out n quads' lightmap rectangles in a grid with a padding of 3 texels at `res`.
inline glm::vec4 grid_cell(int index, int per_row, int res) {
    const float cell = 1.0f / float(per_row), pad = 3.0f / float(res);
    const int cx = index % per_row, cy = index / per_row;
    return {cx * cell + pad, cy * cell + pad, (cx + 1) * cell - pad, (cy + 1) * cell - pad};
}

struct BakeResult {
    FloatImage image;
    TexelSamples texels;
    PassStats stats;
    size_t moved_texels = 0, cut_texels = 0;
};

inline BakeResult bake(const Scene& scene, int res, int passes, RadiosityMapSettings settings = {}) {
    test::gpu();
    BakeResult r;
    r.texels = rasterize_texel_samples(scene, res, res, 2);
    Tracer tracer(scene);
    RadiosityMapBaker baker(scene, r.texels, tracer, settings);
    // In batches, so that a dispatch runs as many passes as its cell
    // (BatchedPassesAreThePassesOneAtATime: the same pixels as one at a time).
    for (int done = 0; done < passes;) {
        const int count = std::min(baker.max_batch(), passes - done);
        r.stats = baker.run_passes(count).back();
        done += count;
    }
    r.image = baker.snapshot();
    r.moved_texels = baker.texels_moved_out_of_geometry();
    r.cut_texels = baker.texels_cut_by_geometry();
    return r;
}

}  // namespace lf::test
