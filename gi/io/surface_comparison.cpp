#include "io/surface_comparison.h"

#include "io/reference_error.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

namespace lf {

namespace {

// A lightmap as a lookup reads it: R, G, B and which texels are a chart's.
struct Lightmap {
    const FloatImage& image;
    const std::vector<float>*rgb[3], *covered;

    Lightmap(const FloatImage& image, const char* which) : image(image) {
        const char* names[4] = {"R", "G", "B", kCoveredChannel};
        const std::vector<float>* found[4];
        for (int c = 0; c < 4; ++c) {
            const auto it = image.channels.find(names[c]);
            if (it == image.channels.end())
                throw std::runtime_error(std::string("the ") + which + " lightmap has no channel " + names[c]);
            found[c] = &it->second;
        }
        rgb[0] = found[0], rgb[1] = found[1], rgb[2] = found[2], covered = found[3];
    }

    // Bilinear at uv (texel centres at half-integers, row 0 at the top:
    // DESIGN.md), over the covered texels among the four taps, renormalized;
    // false where none of them is covered.
    bool read(glm::vec2 uv, glm::dvec3& out) const {
        const double fx = double(uv.x) * image.width - 0.5, fy = double(uv.y) * image.height - 0.5;
        const int x0 = int(std::floor(fx)), y0 = int(std::floor(fy));
        const double ax = fx - x0, ay = fy - y0;
        glm::dvec3 sum(0.0);
        double weights = 0.0;
        for (int k = 0; k < 4; ++k) {
            const int x = x0 + (k & 1), y = y0 + (k >> 1);
            if (x < 0 || y < 0 || x >= image.width || y >= image.height) continue;
            const size_t i = size_t(y) * size_t(image.width) + size_t(x);
            if (!((*covered)[i] > 0.5f)) continue;
            const double w = ((k & 1) ? ax : 1.0 - ax) * ((k >> 1) ? ay : 1.0 - ay);
            sum += w * glm::dvec3((*rgb[0])[i], (*rgb[1])[i], (*rgb[2])[i]);
            weights += w;
        }
        if (!(weights > 0.0)) return false;
        out = sum / weights;
        return true;
    }
};

double uv_area(const Scene& s, size_t t) {
    const glm::uvec3 tri = s.triangles[t];
    const glm::vec2 a = s.uv1[tri.y] - s.uv1[tri.x], b = s.uv1[tri.z] - s.uv1[tri.x];
    return 0.5 * std::abs(double(a.x) * b.y - double(a.y) * b.x);
}

// The same triangles, vertex by vertex, or an error saying where not.
void check_same_triangles(const Scene& bake, const Scene& reference) {
    if (bake.triangles.size() != reference.triangles.size())
        throw std::runtime_error("the bake has " + std::to_string(bake.triangles.size()) +
                                 " triangles and the reference " + std::to_string(reference.triangles.size()) +
                                 ": not bakes of one scene");
    const float tolerance = 1e-4f * std::max(1e-3f, glm::length(reference.bounds.hi - reference.bounds.lo));
    for (size_t t = 0; t < bake.triangles.size(); ++t)
        for (int k = 0; k < 3; ++k)
            if (glm::length(bake.positions[bake.triangles[t][k]] - reference.positions[reference.triangles[t][k]]) >
                tolerance)
                throw std::runtime_error("triangle " + std::to_string(t) +
                                         " lies elsewhere in the bake than in the reference: not bakes of one scene");
}

}  // namespace

SurfaceComparison compare_at_surface_points(const Scene& bake_scene, const FloatImage& bake,
                                            const Scene& reference_scene, const FloatImage& reference,
                                            const SurfacePointOptions& options) {
    check_same_triangles(bake_scene, reference_scene);
    const Lightmap bake_map(bake, "bake's"), reference_map(reference, "reference's");
    // Points area-weighted over the triangles both bakes lightmap.
    std::vector<double> cdf(reference_scene.triangles.size(), 0.0);
    double total = 0.0;
    for (size_t t = 0; t < cdf.size(); ++t) {
        if (uv_area(bake_scene, t) > 0.0 && uv_area(reference_scene, t) > 0.0)
            total += double(reference_scene.triangle_area(t));
        cdf[t] = total;
    }
    SurfaceComparison out;
    if (!(total > 0.0)) return out;
    std::mt19937_64 rng(options.seed);
    std::uniform_real_distribution<double> uniform(0.0, 1.0);
    double sum_sq = 0.0, bake_sum = 0.0, reference_sum = 0.0;
    for (size_t n = 0; n < options.points; ++n) {
        // In (0, total]: the first triangle whose share holds it has one.
        const double at = (1.0 - uniform(rng)) * total;
        const size_t t = size_t(std::lower_bound(cdf.begin(), cdf.end(), at) - cdf.begin());
        const double r1 = std::sqrt(uniform(rng)), r2 = uniform(rng);
        const float b1 = float(r1 * (1.0 - r2)), b2 = float(r1 * r2), b0 = 1.0f - b1 - b2;
        auto uv_in = [&](const Scene& s) {
            const glm::uvec3 tri = s.triangles[t];
            return b0 * s.uv1[tri.x] + b1 * s.uv1[tri.y] + b2 * s.uv1[tri.z];
        };
        glm::dvec3 b, r;
        if (!bake_map.read(uv_in(bake_scene), b) || !reference_map.read(uv_in(reference_scene), r)) continue;
        const glm::dvec3 d = b - r;
        sum_sq += glm::dot(d, d) / 3.0;
        bake_sum += (b.r + b.g + b.b) / 3.0;
        reference_sum += (r.r + r.g + r.b) / 3.0;
        ++out.points;
    }
    if (out.points == 0) return out;
    const double n = double(out.points);
    out.rmse = std::sqrt(sum_sq / n);
    out.reference_mean = reference_sum / n;
    if (out.reference_mean > 0.0) {
        out.relative_rmse = out.rmse / out.reference_mean;
        out.bias = bake_sum / reference_sum - 1.0;
    }
    return out;
}

}  // namespace lf
