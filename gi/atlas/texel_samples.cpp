#include "atlas/texel_samples.h"

#include "util/parallel.h"
#include "util/math.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <optional>
#include <stdexcept>

namespace lf {
namespace {

// How deep (in texels) a triangle must reach into a texel to touch it. UVs
// are floats: at 8192² one float step is ~2e-4 texel, and a chart edge that
// lies exactly on a texel border must not spill into the padding beyond it.
constexpr double kTouchDepth = 1e-3;

// A triangle's UV1 in pixel units, counter-clockwise after `orientation`.
struct PixelTriangle {
    std::array<glm::dvec2, 3> p;
    double area2 = 0.0;  // signed, twice the area
    double orientation = 1.0;

    PixelTriangle(const Scene& scene, size_t t, int width, int height) {
        const glm::uvec3& tri = scene.triangles[t];
        const glm::dvec2 scale(width, height);
        for (int k = 0; k < 3; ++k) p[size_t(k)] = glm::dvec2(scene.uv1[tri[k]]) * scale;
        area2 = cross2(p[1] - p[0], p[2] - p[0]);
        orientation = area2 < 0.0 ? -1.0 : 1.0;
    }
    bool finite() const {
        for (const auto& q : p)
            if (!std::isfinite(q.x) || !std::isfinite(q.y)) return false;
        return true;
    }
    bool degenerate() const { return !(std::abs(area2) > 1e-12); }
    // Signed distance-like edge function, >= 0 inside.
    double edge(int k, glm::dvec2 q) const {
        const glm::dvec2 a = p[size_t(k)], b = p[size_t((k + 1) % 3)];
        return orientation * cross2(b - a, q - a);
    }
    bool contains(glm::dvec2 q) const { return edge(0, q) >= 0.0 && edge(1, q) >= 0.0 && edge(2, q) >= 0.0; }
    // Separating-axis test against texel [x, x+1] x [y, y+1], requiring a
    // reach of kTouchDepth (a shared border alone does not count).
    bool touches_texel(int x, int y) const {
        const glm::dvec2 lo = glm::min(glm::min(p[0], p[1]), p[2]), hi = glm::max(glm::max(p[0], p[1]), p[2]);
        if (hi.x <= x + kTouchDepth || lo.x >= x + 1 - kTouchDepth) return false;
        if (hi.y <= y + kTouchDepth || lo.y >= y + 1 - kTouchDepth) return false;
        for (int k = 0; k < 3; ++k) {
            const double len = glm::length(p[size_t((k + 1) % 3)] - p[size_t(k)]);
            double reach = -1e300;
            for (glm::dvec2 corner :
                 {glm::dvec2(x, y), glm::dvec2(x + 1, y), glm::dvec2(x, y + 1), glm::dvec2(x + 1, y + 1)})
                reach = std::max(reach, edge(k, corner));
            if (reach <= kTouchDepth * len) return false;
        }
        return true;
    }
    glm::dvec2 centroid() const { return (p[0] + p[1] + p[2]) / 3.0; }
    // (b1, b2) of a point, clamped onto the triangle.
    glm::vec2 barycentrics(glm::dvec2 q) const {
        if (degenerate()) return glm::vec2(1.0f / 3.0f);
        double b1 = cross2(q - p[0], p[2] - p[0]) / area2;
        double b2 = cross2(p[1] - p[0], q - p[0]) / area2;
        b1 = std::clamp(b1, 0.0, 1.0);
        b2 = std::clamp(b2, 0.0, 1.0);
        if (b1 + b2 > 1.0) {
            const double s = b1 + b2;
            b1 /= s;
            b2 /= s;
        }
        return glm::vec2(float(b1), float(b2));
    }
};

// The centroid of the part of the triangle inside texel (x, y): the triangle
// clipped to the texel square (Sutherland-Hodgman), so the point lies in both.
// A triangle clipped by four half-planes keeps at most seven corners.
glm::dvec2 centroid_inside_texel(const PixelTriangle& tri, int x, int y) {
    std::array<glm::dvec2, 8> poly{tri.p[0], tri.p[1], tri.p[2]}, next;
    size_t count = 3;
    auto clip = [&](auto inside_distance) {  // keeps points with distance >= 0
        size_t kept = 0;
        for (size_t i = 0; i < count; ++i) {
            const glm::dvec2 a = poly[i], b = poly[(i + 1) % count];
            const double da = inside_distance(a), db = inside_distance(b);
            if (da >= 0.0) next[kept++] = a;
            if ((da >= 0.0) != (db >= 0.0)) next[kept++] = a + (b - a) * (da / (da - db));
        }
        poly = next;
        count = kept;
    };
    clip([&](glm::dvec2 q) { return q.x - x; });
    clip([&](glm::dvec2 q) { return x + 1 - q.x; });
    clip([&](glm::dvec2 q) { return q.y - y; });
    clip([&](glm::dvec2 q) { return y + 1 - q.y; });
    if (count == 0) return glm::clamp(tri.centroid(), glm::dvec2(x, y), glm::dvec2(x + 1, y + 1));
    double area2 = 0.0;
    glm::dvec2 weighted(0.0), mean(0.0);
    for (size_t i = 0; i < count; ++i) {
        const glm::dvec2 a = poly[i], b = poly[(i + 1) % count];
        const double c = cross2(a, b);
        area2 += c;
        weighted += (a + b) * c;
        mean += a;
    }
    if (std::abs(area2) > 1e-12) return weighted / (3.0 * area2);
    return mean / double(count);
}

// The rows [first, last] of the image that a triangle's UV bounding box
// reaches (first > last where none).
glm::ivec2 triangle_rows(const PixelTriangle& tri, int height) {
    const double lo = std::min({tri.p[0].y, tri.p[1].y, tri.p[2].y});
    const double hi = std::max({tri.p[0].y, tri.p[1].y, tri.p[2].y});
    return {std::max(0, int(std::floor(lo))), std::min(height - 1, int(std::floor(hi)))};
}

// Calls emit(x, y, pixel_position) for every sample of a finite,
// non-degenerate triangle in rows [rows.x, rows.y]: covered sub-positions,
// else one conservative sample per touched texel; returns whether it
// emitted any. Without kPositions, emit(x, y) only (counting), and the
// conservative samples' positions are not computed.
template <bool kPositions, typename Emit>
bool rasterize_rows(const PixelTriangle& tri, int width, int n, glm::ivec2 rows, Emit&& emit) {
    const glm::dvec2 lo = glm::min(glm::min(tri.p[0], tri.p[1]), tri.p[2]);
    const glm::dvec2 hi = glm::max(glm::max(tri.p[0], tri.p[1]), tri.p[2]);
    const int x0 = std::max(0, int(std::floor(lo.x))), x1 = std::min(width - 1, int(std::floor(hi.x)));
    bool any = false;
    for (int y = rows.x; y <= rows.y; ++y)
        for (int x = x0; x <= x1; ++x) {
            bool covered = false;
            for (int j = 0; j < n; ++j)
                for (int i = 0; i < n; ++i) {
                    const glm::dvec2 q(x + (i + 0.5) / n, y + (j + 0.5) / n);
                    if (tri.contains(q)) {
                        if constexpr (kPositions) emit(x, y, q);
                        else emit(x, y);
                        covered = true;
                    }
                }
            if (!covered && tri.touches_texel(x, y)) {
                if constexpr (kPositions) emit(x, y, centroid_inside_texel(tri, x, y));
                else emit(x, y);
                covered = true;
            }
            any = any || covered;
        }
    return any;
}

// The one sample of a finite triangle that rasterizes to none (degenerate
// in UV, or smaller than kTouchDepth everywhere: it still owns its texel),
// at its UV centroid, if that lies inside the image.
std::optional<glm::dvec2> centroid_sample(const PixelTriangle& tri, int width, int height) {
    const glm::dvec2 c = tri.centroid();
    if (c.x < 0.0 || c.y < 0.0 || c.x >= width || c.y >= height) return std::nullopt;
    return c;
}

// Calls emit(x, y, pixel_position) for every sample of triangle t: covered
// sub-positions, else one conservative sample per touched texel, and at
// least one sample for any triangle with a finite UV inside the image.
template <typename Emit>
void rasterize_triangle(const Scene& scene, size_t t, int width, int height, int n, Emit&& emit) {
    const PixelTriangle tri(scene, t, width, height);
    if (!tri.finite()) return;
    if (!tri.degenerate() && rasterize_rows<true>(tri, width, n, triangle_rows(tri, height), emit)) return;
    if (const auto c = centroid_sample(tri, width, height)) emit(int(c->x), int(c->y), *c);
}

// The image in bands of rows, each with the finite, non-degenerate
// triangles whose rows reach into it, ascending: the passes of
// rasterize_texel_samples run a band per task, and each pixel's samples come
// out in triangle order, as one pass over the triangles gives them, on any
// number of threads.
struct RowBands {
    int rows = 16;                                 // per band
    std::vector<std::vector<uint32_t>> triangles;  // per band
    // A triangle's rows within band b.
    glm::ivec2 rows_of(size_t b, const PixelTriangle& tri, int height) const {
        const glm::ivec2 all = triangle_rows(tri, height);
        return {std::max(all.x, int(b) * rows), std::min(all.y, int(b + 1) * rows - 1)};
    }
};

RowBands row_bands(const std::vector<PixelTriangle>& tris, int height) {
    RowBands bands;
    bands.triangles.resize(size_t((height + bands.rows - 1) / bands.rows));
    for (uint32_t t = 0; t < tris.size(); ++t) {
        if (!tris[t].finite() || tris[t].degenerate()) continue;
        const glm::ivec2 rows = triangle_rows(tris[t], height);
        for (int b = rows.x / bands.rows; b <= rows.y / bands.rows && rows.x <= rows.y; ++b)
            bands.triangles[size_t(b)].push_back(t);
    }
    return bands;
}

void check_size(int width, int height, int subsamples) {
    if (width <= 0 || height <= 0 || int64_t(width) * height > (int64_t(1) << 30) || subsamples < 1 || subsamples > 16)
        throw std::invalid_argument("texel samples: bad atlas size or subsample count");
}

// For every uncovered texel within `radius` of a covered one, the nearest
// covered texel (Euclidean; ties go to the first in scan order). Charts are
// at least `padding` texels apart, so the nearest texel of a ring within
// padding/2 of a chart is that chart's own.
std::vector<std::pair<uint32_t, uint32_t>> dilation_map(const std::vector<uint32_t>& count, int width, int height,
                                                        int radius) {
    std::vector<std::pair<uint32_t, uint32_t>> map;
    if (radius <= 0) return map;
    std::vector<std::vector<std::pair<uint32_t, uint32_t>>> rows(
        static_cast<size_t>(height));  // each row's, in scan order
    parallel_for(size_t(height), 16, [&](size_t row) {
        const int y = int(row);
        for (int x = 0; x < width; ++x) {
            if (count[size_t(y) * size_t(width) + size_t(x)] != 0) continue;
            int best = INT32_MAX;
            uint32_t best_pixel = 0;
            for (int dy = -radius; dy <= radius; ++dy) {
                const int yy = y + dy;
                if (yy < 0 || yy >= height) continue;
                for (int dx = -radius; dx <= radius; ++dx) {
                    const int xx = x + dx, d2 = dx * dx + dy * dy;
                    if (xx < 0 || xx >= width || d2 >= best || d2 > radius * radius) continue;
                    const uint32_t pixel = uint32_t(yy) * uint32_t(width) + uint32_t(xx);
                    if (count[pixel] != 0) {
                        best = d2;
                        best_pixel = pixel;
                    }
                }
            }
            if (best != INT32_MAX) rows[row].emplace_back(uint32_t(y) * uint32_t(width) + uint32_t(x), best_pixel);
        }
    });
    for (const auto& r : rows) map.insert(map.end(), r.begin(), r.end());
    return map;
}

TexelSample make_sample(const Scene& scene, uint32_t t, glm::vec2 bary) {
    const glm::uvec3& tri = scene.triangles[t];
    const float b0 = 1.0f - bary.x - bary.y;
    TexelSample s;
    s.position = b0 * scene.positions[tri.x] + bary.x * scene.positions[tri.y] + bary.y * scene.positions[tri.z];
    s.geometric_normal = scene.geometric_normal(t);
    const glm::vec3 n = b0 * scene.normals[tri.x] + bary.x * scene.normals[tri.y] + bary.y * scene.normals[tri.z];
    const float len = glm::length(n);
    s.normal = len > 1e-12f ? n / len : s.geometric_normal;
    s.triangle = t;
    s.bary = bary;
    return s;
}

template <typename Pixel>
void apply_dilation(const TexelSamples& texels, std::vector<Pixel>& image) {
    if (image.size() != size_t(texels.width) * size_t(texels.height))
        throw std::invalid_argument("dilate: image size does not match the atlas");
    for (const auto& [to, from] : texels.dilation) image[to] = image[from];
}

// Each covered texel's albedo and emission, averaged over its samples, and
// its world size (TexelSamples::texel_world_size). A ray stops on a
// see-through surface only where the surface is there (a cut-out's opaque
// part; a blend by its alpha), so the albedo a hit there reflects is the
// mean over the samples weighted by how much of the surface is there
// (1 - transmittance); a texel none of whose samples is there keeps the
// plain mean. grey_white_room's cut-out leaves, whose cut-away parts are
// bright in their texture, read +0.9% over the room against the path
// tracer (epochs and final gather alike) when every sample counted.
void average_over_samples(const Scene& scene, const std::vector<PixelTriangle>& tris, TexelSamples& out) {
    std::vector<float> world_per_texel(tris.size());
    for (size_t t = 0; t < tris.size(); ++t) {
        const double uv_area = 0.5 * std::abs(tris[t].area2);
        world_per_texel[t] = uv_area > 1e-12 ? float(std::sqrt(scene.triangle_area(t) / uv_area)) : 0.0f;
    }
    const size_t covered = out.texels.size();
    out.albedo.resize(covered);
    out.emission.resize(covered);
    out.texel_world_size.resize(covered);
    parallel_for(covered, 1024, [&](size_t i) {
        glm::vec3 albedo(0.0f), present_albedo(0.0f), emission(0.0f);
        float size = 0.0f, present = 0.0f;
        for (uint32_t s = out.first_sample[i]; s < out.first_sample[i + 1]; ++s) {
            const TexelSample& sample = out.samples[s];
            const glm::vec3 a = scene.albedo_at(sample.triangle, sample.bary);
            const glm::vec3 passes = scene.transmittance_at(sample.triangle, sample.bary);
            const float there = std::clamp(1.0f - (passes.r + passes.g + passes.b) / 3.0f, 0.0f, 1.0f);
            albedo += a;
            present_albedo += there * a;
            present += there;
            emission += scene.emission_at(sample.triangle, sample.bary);
            size = std::max(size, world_per_texel[sample.triangle]);
        }
        const float inv = 1.0f / float(out.sample_count(i));
        out.albedo[i] = present > 0.0f ? present_albedo / present : albedo * inv;
        out.emission[i] = emission * inv;
        out.texel_world_size[i] = size;
    });
}

}  // namespace

TexelSamples rasterize_texel_samples(const Scene& scene, int width, int height, int subsamples_per_axis,
                                     int dilate_texels) {
    check_size(width, height, subsamples_per_axis);
    const int n = subsamples_per_axis;
    const size_t pixels = size_t(width) * size_t(height);
    std::vector<PixelTriangle> tris;
    tris.reserve(scene.triangles.size());
    for (size_t t = 0; t < scene.triangles.size(); ++t) tris.emplace_back(scene, t, width, height);
    const RowBands bands = row_bands(tris, height);

    // Pass 1: samples per texel, to lay the sample array out by texel.
    std::vector<uint32_t> count(pixels, 0);
    std::vector<uint8_t> rasterized(tris.size(), 0);  // emitted a sample in some band
    parallel_for(bands.triangles.size(), 1, [&](size_t b) {
        for (const uint32_t t : bands.triangles[b]) {
            const bool any =
                rasterize_rows<false>(tris[t], width, n, bands.rows_of(b, tris[t], height),
                                      [&](int x, int y) { ++count[size_t(y) * size_t(width) + size_t(x)]; });
            if (any) std::atomic_ref<uint8_t>(rasterized[t]).store(1, std::memory_order_relaxed);
        }
    });
    // Triangles that rasterized to nothing: one sample at the centroid, in
    // its band's pass below (a pixel's samples in triangle order).
    std::vector<std::vector<uint32_t>> centroids(bands.triangles.size());
    for (uint32_t t = 0; t < tris.size(); ++t) {
        if (rasterized[t] || !tris[t].finite()) continue;
        if (const auto c = centroid_sample(tris[t], width, height)) {
            ++count[size_t(c->y) * size_t(width) + size_t(c->x)];
            centroids[size_t(c->y) / size_t(bands.rows)].push_back(t);
        }
    }

    TexelSamples out;
    out.width = width;
    out.height = height;
    std::vector<uint32_t> cursor(pixels, 0);  // next free sample slot per pixel
    out.first_sample.push_back(0);
    for (size_t pixel = 0; pixel < pixels; ++pixel) {
        if (count[pixel] == 0) continue;
        cursor[pixel] = out.first_sample.back();
        out.texels.push_back(uint32_t(pixel));
        out.first_sample.push_back(out.first_sample.back() + count[pixel]);
    }

    // Pass 2: the samples themselves, a band per task, each band's
    // triangles and centroid samples merged in triangle order.
    out.samples.resize(out.first_sample.back());
    parallel_for(bands.triangles.size(), 1, [&](size_t b) {
        auto write = [&](uint32_t t, int x, int y, glm::dvec2 q) {
            out.samples[cursor[size_t(y) * size_t(width) + size_t(x)]++] =
                make_sample(scene, t, tris[t].barycentrics(q));
        };
        const std::vector<uint32_t>& rows = bands.triangles[b];
        const std::vector<uint32_t>& lone = centroids[b];
        for (size_t i = 0, j = 0; i < rows.size() || j < lone.size();) {
            if (j == lone.size() || (i < rows.size() && rows[i] <= lone[j])) {
                const uint32_t t = rows[i++];
                rasterize_rows<true>(tris[t], width, n, bands.rows_of(b, tris[t], height),
                                     [&](int x, int y, glm::dvec2 q) { write(t, x, y, q); });
            } else {
                const uint32_t t = lone[j++];
                const glm::dvec2 c = tris[t].centroid();
                write(t, int(c.x), int(c.y), c);
            }
        }
    });

    average_over_samples(scene, tris, out);
    out.dilation = dilation_map(count, width, height, dilate_texels);
    return out;
}

std::vector<uint8_t> coverage_mask(const Scene& scene, int width, int height) {
    check_size(width, height, 1);
    std::vector<uint8_t> mask(size_t(width) * size_t(height), 0);
    for (size_t t = 0; t < scene.triangles.size(); ++t)
        rasterize_triangle(scene, t, width, height, 1,
                           [&](int x, int y, glm::dvec2) { mask[size_t(y) * size_t(width) + size_t(x)] = 1; });
    return mask;
}

void dilate(const TexelSamples& texels, std::vector<glm::vec4>& image) { apply_dilation(texels, image); }
void dilate(const TexelSamples& texels, std::vector<glm::vec3>& image) { apply_dilation(texels, image); }

}  // namespace lf
