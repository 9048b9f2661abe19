// What the lightmap tests share: a bake of a scene built in code, and the
// form factors its direct light is known by in closed form.
#pragma once

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

// Irradiance/pi at a point on a plane from a parallel rectangle of radiance 1
// whose corner lies straight above it at height c, sides a, b: the
// differential-area-to-rectangle form factor (Howell's catalogue, C-11).
inline double corner_form_factor(double a, double b, double c) {
    const double x = a / c, y = b / c;
    const double sx = std::sqrt(1 + x * x), sy = std::sqrt(1 + y * y);
    return (x / sx * std::atan(y / sx) + y / sy * std::atan(x / sy)) / (2.0 * M_PI);
}

// Any point under a rectangle [x0,x1]x[z0,z1] at height h, by splitting it at the point.
inline double rectangle_form_factor(double px, double pz, double x0, double x1, double z0, double z1, double h) {
    // Signed rectangles from the point to each corner: F = F(x1,z1) - F(x0,z1) - F(x1,z0) + F(x0,z0).
    auto part = [&](double a, double b) {
        return (a == 0.0 || b == 0.0) ? 0.0 : corner_form_factor(std::abs(a), std::abs(b), h);
    };
    auto sgn = [](double v) { return v < 0 ? -1.0 : 1.0; };
    double f = 0.0;
    for (double xe : {x0, x1})
        for (double ze : {z0, z1}) {
            const double a = xe - px, b = ze - pz;
            const double s = sgn(a) * sgn(b) * (xe == x0 ? -1.0 : 1.0) * (ze == z0 ? -1.0 : 1.0);
            f += s * part(a, b);
        }
    return f;
}

}  // namespace lf::test
