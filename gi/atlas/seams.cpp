#include "atlas/seams.h"

#include "atlas/mesh_topology.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <unordered_map>

namespace lf {
namespace {

constexpr float kUvTolerance = 1e-6f;
const float kSmoothCos = std::cos(glm::radians(10.0f));

struct Tap {
    uint32_t pixel;
    float weight;
};

// The four texels a bilinear lookup at `uv` reads, and their weights.
std::array<Tap, 4> bilinear_taps(int width, int height, glm::vec2 uv) {
    const double x = double(uv.x) * width - 0.5, y = double(uv.y) * height - 0.5;
    const double fx0 = std::floor(x), fy0 = std::floor(y);
    const float fx = float(x - fx0), fy = float(y - fy0);
    auto clamp_x = [&](double v) { return uint32_t(std::clamp(v, 0.0, double(width - 1))); };
    auto clamp_y = [&](double v) { return uint32_t(std::clamp(v, 0.0, double(height - 1))); };
    const uint32_t x0 = clamp_x(fx0), x1 = clamp_x(fx0 + 1), y0 = clamp_y(fy0), y1 = clamp_y(fy0 + 1);
    const auto w = uint32_t(width);
    return {{{y0 * w + x0, (1 - fx) * (1 - fy)},
             {y0 * w + x1, fx * (1 - fy)},
             {y1 * w + x0, (1 - fx) * fy},
             {y1 * w + x1, fx * fy}}};
}

void check_image(const std::vector<glm::vec4>& image, int width, int height) {
    if (width <= 0 || height <= 0 || image.size() != size_t(width) * size_t(height))
        throw std::invalid_argument("seams: image size does not match width x height");
}

double max_component(glm::dvec4 v) { return std::max(std::max(v.x, v.y), std::max(v.z, v.w)); }

glm::vec2 seam_point(glm::vec2 p0, glm::vec2 p1, int k, int samples) {
    return glm::mix(p0, p1, (float(k) + 0.5f) / float(samples));
}

}  // namespace

std::vector<SeamEdge> find_seams(const Scene& scene) {
    const auto weld = atlas_detail::weld_positions(scene.positions, atlas_detail::weld_tolerance(scene));
    const atlas_detail::SharedEdges shared = atlas_detail::find_shared_edges(scene.triangles, weld);
    const std::vector<uint8_t> without_lightmap = scene.triangles_without_lightmap();
    std::vector<SeamEdge> seams;
    auto compare = [&](atlas_detail::EdgeRef a, atlas_detail::EdgeRef b) {
        if (without_lightmap[a.triangle] || without_lightmap[b.triangle]) return;
        const glm::uvec3& ta = scene.triangles[a.triangle];
        const glm::uvec3& tb = scene.triangles[b.triangle];
        const uint32_t a0 = ta[int(a.edge)], a1 = ta[int((a.edge + 1) % 3)];
        uint32_t b0 = tb[int(b.edge)], b1 = tb[int((b.edge + 1) % 3)];
        if (weld[b0] != weld[a0]) std::swap(b0, b1);
        SeamEdge seam{scene.uv1[a0], scene.uv1[a1], scene.uv1[b0], scene.uv1[b1]};
        const float apart = std::max(glm::length(seam.a0 - seam.b0), glm::length(seam.a1 - seam.b1));
        if (!(apart > kUvTolerance)) return;
        seam.smooth = glm::dot(scene.normals[a0], scene.normals[b0]) >= kSmoothCos &&
                      glm::dot(scene.normals[a1], scene.normals[b1]) >= kSmoothCos;
        seams.push_back(seam);
    };
    constexpr uint32_t kAllPairsUpTo = 8;
    for (size_t g = 0; g < shared.group_count(); ++g) {
        const uint32_t begin = shared.group_start[g], end = shared.group_start[g + 1];
        if (end - begin <= kAllPairsUpTo) {
            for (uint32_t i = begin; i < end; ++i)
                for (uint32_t j = i + 1; j < end; ++j) compare(shared.edges[i], shared.edges[j]);
        } else {
            for (uint32_t i = begin; i + 1 < end; ++i) compare(shared.edges[i], shared.edges[i + 1]);
        }
    }
    return seams;
}

glm::vec4 sample_bilinear(const std::vector<glm::vec4>& image, int width, int height, glm::vec2 uv) {
    check_image(image, width, height);
    glm::vec4 sum(0.0f);
    for (const Tap& tap : bilinear_taps(width, height, uv)) sum += tap.weight * image[tap.pixel];
    return sum;
}

double seam_metric(const std::vector<SeamEdge>& seams, const std::vector<glm::vec4>& image, int width, int height,
                   int samples_per_edge) {
    check_image(image, width, height);
    if (seams.empty() || samples_per_edge <= 0) return 0.0;
    double sum = 0.0;
    for (const SeamEdge& seam : seams)
        for (int k = 0; k < samples_per_edge; ++k) {
            const glm::vec4 a =
                sample_bilinear(image, width, height, seam_point(seam.a0, seam.a1, k, samples_per_edge));
            const glm::vec4 b =
                sample_bilinear(image, width, height, seam_point(seam.b0, seam.b1, k, samples_per_edge));
            const glm::vec3 d = glm::abs(glm::vec3(a) - glm::vec3(b));
            sum += (double(d.x) + d.y + d.z) / 3.0;
        }
    return sum / (double(seams.size()) * samples_per_edge);
}

namespace {

using SeamRow = SeamStitcher::Row;
using RowTap = SeamStitcher::RowTap;

// Rounds of the active-set solve below; after the first, each starts from the
// last solution and needs few steps (it only moves the texels around the
// newly held ones).
constexpr int kMaxRounds = 4;
constexpr int kLaterRoundDivisor = 4;

// Conjugate gradients on (MᵀM + λI) x = λ x0 over the components `free_mask`
// marks (1), the others held at their value in x (0 when called from the
// active set), starting from x. The four channels are solved together,
// independently.
void solve_normal_equations(const std::vector<SeamRow>& rows, const std::vector<glm::vec4>& original,
                            const std::vector<glm::vec4>& free_mask, float lambda, int iterations,
                            std::vector<glm::vec4>& x) {
    const size_t n = x.size();
    auto apply = [&](const std::vector<glm::vec4>& v, std::vector<glm::vec4>& out) {
        for (size_t i = 0; i < n; ++i) out[i] = lambda * v[i];
        for (const SeamRow& row : rows) {
            glm::vec4 residual(0.0f);
            for (const RowTap& tap : row) residual += tap.weight * v[tap.unknown];
            for (const RowTap& tap : row) out[tap.unknown] += tap.weight * residual;
        }
        for (size_t i = 0; i < n; ++i) out[i] *= free_mask[i];
    };
    auto dot = [&](const std::vector<glm::vec4>& a, const std::vector<glm::vec4>& b) {
        glm::dvec4 sum(0.0);
        for (size_t i = 0; i < n; ++i) sum += glm::dvec4(a[i] * b[i]);
        return sum;
    };
    std::vector<glm::vec4> r(n), p(n), ap(n);
    apply(x, ap);  // held components are 0 and contribute nothing
    for (size_t i = 0; i < n; ++i) r[i] = free_mask[i] * (lambda * original[i]) - ap[i];
    p = r;
    glm::dvec4 rr = dot(r, r);
    const double tolerance = 1e-12 * std::max(1.0, max_component(dot(original, original)));
    for (int it = 0; it < iterations && max_component(rr) > tolerance; ++it) {
        apply(p, ap);
        const glm::dvec4 pap = dot(p, ap);
        glm::vec4 alpha, beta;
        for (int c = 0; c < 4; ++c) alpha[c] = pap[c] > 0.0 ? float(rr[c] / pap[c]) : 0.0f;
        for (size_t i = 0; i < n; ++i) {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
        }
        const glm::dvec4 rr_next = dot(r, r);
        for (int c = 0; c < 4; ++c) beta[c] = rr[c] > 0.0 ? float(rr_next[c] / rr[c]) : 0.0f;
        for (size_t i = 0; i < n; ++i) p[i] = r[i] + beta * p[i];
        rr = rr_next;
    }
}

}  // namespace

SeamStitcher::SeamStitcher(const std::vector<SeamEdge>& seams, int width, int height, int samples_per_edge)
    : width_(width), height_(height) {
    if (width <= 0 || height <= 0) throw std::invalid_argument("seams: an atlas of no texels");
    if (samples_per_edge <= 0) return;
    // Unknowns: the texels some seam lookup reads. Each seam point is one
    // row: +bilinear weights on side A, -bilinear weights on side B.
    std::unordered_map<uint32_t, uint32_t> unknown_of_pixel;
    rows_.reserve(seams.size() * size_t(samples_per_edge));
    auto unknown = [&](uint32_t pixel) {
        auto [it, inserted] = unknown_of_pixel.try_emplace(pixel, uint32_t(pixel_of_unknown_.size()));
        if (inserted) pixel_of_unknown_.push_back(pixel);
        return it->second;
    };
    for (const SeamEdge& seam : seams)
        for (int k = 0; k < samples_per_edge; ++k) {
            const auto a = bilinear_taps(width, height, seam_point(seam.a0, seam.a1, k, samples_per_edge));
            const auto b = bilinear_taps(width, height, seam_point(seam.b0, seam.b1, k, samples_per_edge));
            SeamRow row;
            for (size_t i = 0; i < 4; ++i) {
                row[i] = {unknown(a[i].pixel), a[i].weight};
                row[4 + i] = {unknown(b[i].pixel), -b[i].weight};
            }
            rows_.push_back(row);
        }
}

void SeamStitcher::stitch(std::vector<glm::vec4>& image, float lambda, int iterations, bool non_negative) const {
    check_image(image, width_, height_);
    if (rows_.empty()) return;
    // Normal equations (MᵀM + λI) x = λ x0, solved by conjugate gradients
    // from x0; the matrix is symmetric positive definite for λ > 0.
    // Irradiance is never negative, and the unconstrained least-squares
    // solution can be (a dark texel pulled below 0 by bright neighbours across
    // a seam: 507 texels on the staircase at 512²). So the solve is repeated
    // on the free components only, those that went negative held at 0 (an
    // active-set method; `free_mask` is 1 for a free component, 0 for a held one),
    // until none does; anything still negative after kMaxRounds is clamped.
    const size_t n = pixel_of_unknown_.size();
    std::vector<glm::vec4> original(n), x(n), free_mask(n, glm::vec4(1.0f));
    for (size_t i = 0; i < n; ++i) original[i] = x[i] = image[pixel_of_unknown_[i]];
    for (int round = 0; round < kMaxRounds; ++round) {
        solve_normal_equations(rows_, original, free_mask, lambda,
                               round == 0 ? iterations : std::max(1, iterations / kLaterRoundDivisor), x);
        if (!non_negative) break;  // signed data: the unconstrained solution is the answer
        bool held_more = false;
        for (size_t i = 0; i < n; ++i)
            for (int c = 0; c < 4; ++c)
                if (x[i][c] < 0.0f && free_mask[i][c] != 0.0f) {
                    free_mask[i][c] = 0.0f;
                    x[i][c] = 0.0f;
                    held_more = true;
                }
        if (!held_more) break;
    }
    if (non_negative)
        for (size_t i = 0; i < n; ++i) x[i] = glm::max(x[i], glm::vec4(0.0f));
    for (size_t i = 0; i < n; ++i) image[pixel_of_unknown_[i]] = x[i];
}

void stitch_seams(const std::vector<SeamEdge>& seams, std::vector<glm::vec4>& image, int width, int height,
                  int samples_per_edge, float lambda, int iterations, bool non_negative) {
    check_image(image, width, height);
    if (seams.empty() || samples_per_edge <= 0) return;
    SeamStitcher(seams, width, height, samples_per_edge).stitch(image, lambda, iterations, non_negative);
}

}  // namespace lf
