// Lightmap texels as sample points on the surfaces (DESIGN.md "Data flow":
// texel samples), found by rasterizing every triangle's UV1 into the atlas.
//
// Each triangle adds samples to every texel it overlaps:
//   * at each of n x n stratified sub-positions of the texel that it covers
//     (sub-position (i, j) at (x + (i+½)/n, y + (j+½)/n)), or,
//   * if it covers none of them (a thin or small triangle), one sample at the
//     centroid of the part of the triangle inside the texel (conservative
//     rasterization: whatever touches a texel owns it, so slivers and tiny
//     triangles still get texels).
// Every sample therefore lies on its triangle and inside its texel's footprint.
// A triangle that is degenerate in UV (no area) gets one sample at its UV
// centroid. Texels that no triangle touches are "uncovered"; the dilation map
// says which covered texel each uncovered texel near a chart copies.
#pragma once

#include "scene/scene.h"

#include <glm/glm.hpp>

#include <cstdint>
#include <memory>
#include <type_traits>
#include <utility>
#include <vector>

namespace lf {

struct TexelSample {
    glm::vec3 position;          // world space, on the triangle
    glm::vec3 normal;            // shading normal, interpolated and normalized
    glm::vec3 geometric_normal;  // unit (zero for a degenerate triangle)
    uint32_t triangle;
    glm::vec2 bary;  // (b1, b2) as for Scene::albedo_at
};

// Allocates like std::allocator but leaves new elements default-initialized
// (uninitialized, for TexelSample) rather than zeroed: the samples are each
// written once, by rasterize_texel_samples's bands in parallel, and zeroing
// them first on one thread, page faults and all, took a fifth of its time
// (monkey.glb at 1024², 2026-11-26).
template <typename T>
struct DefaultInitAllocator : std::allocator<T> {
    template <typename U>
    struct rebind {
        using other = DefaultInitAllocator<U>;
    };
    template <typename U>
    void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
        ::new (static_cast<void*>(p)) U;
    }
    template <typename U, typename... Args>
    void construct(U* p, Args&&... args) {
        ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
};

struct TexelSamples {
    int width = 0;
    int height = 0;
    // Covered texels, ascending pixel index y * width + x.
    std::vector<uint32_t> texels;
    // Samples of covered texel i: samples[first_sample[i] .. first_sample[i+1]).
    std::vector<uint32_t> first_sample;
    std::vector<TexelSample, DefaultInitAllocator<TexelSample>> samples;
    // Per covered texel, averaged over its samples:
    std::vector<glm::vec3> albedo;
    std::vector<glm::vec3> emission;
    // World-space side of the texel: sqrt of the world area one texel covers
    // on its triangles, the largest over its samples' triangles. The scale
    // for ray offsets and leak tests.
    std::vector<float> texel_world_size;
    // (uncovered pixel, covered pixel it copies): every uncovered texel within
    // `dilate_texels` of a covered one, paired with its nearest covered texel.
    std::vector<std::pair<uint32_t, uint32_t>> dilation;

    size_t covered_count() const { return texels.size(); }
    uint32_t sample_count(size_t i) const { return first_sample[i + 1] - first_sample[i]; }
};

TexelSamples rasterize_texel_samples(const Scene& scene, int width, int height, int subsamples_per_axis = 2,
                                     int dilate_texels = 3);

// 1 where some triangle touches the texel (the covered texels above), 0 elsewhere.
std::vector<uint8_t> coverage_mask(const Scene& scene, int width, int height);

// Copies covered texels into the uncovered ring around every chart
// (TexelSamples::dilation), so bilinear lookups near chart borders read the
// chart's own values. `image` is width x height, row-major from the top.
void dilate(const TexelSamples& texels, std::vector<glm::vec4>& image);
void dilate(const TexelSamples& texels, std::vector<glm::vec3>& image);

}  // namespace lf
