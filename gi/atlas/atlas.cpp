#include "atlas/atlas.h"

#include "atlas/mesh_topology.h"
#include "atlas/texel_samples.h"

#include <glm/gtc/constants.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <optional>
#include <stdexcept>
#include <string>
#include <unordered_map>

namespace lf {
namespace {

using atlas_detail::EdgeRef;
using atlas_detail::SharedEdges;
using Tri2 = std::array<glm::dvec2, 3>;
using CornerUVs = std::vector<std::array<glm::vec2, 3>>;  // per triangle, per corner

constexpr int kDefaultResolution = kDefaultAtlasResolution;
constexpr uint32_t kNone = UINT32_MAX;

// ---------------------------------------------------------------------------
// Adjacency: triangles that share an edge (by welded position).

struct TriangleAdjacency {
    std::vector<uint32_t> start;  // neighbours of t: neighbours[start[t] .. start[t+1])
    std::vector<uint32_t> neighbours;
};

TriangleAdjacency triangle_adjacency(size_t triangle_count, const SharedEdges& shared) {
    // An edge shared by more than a handful of triangles (non-manifold fins)
    // links each triangle only to the next in the group, which keeps the
    // adjacency linear in size.
    constexpr uint32_t kAllPairsUpTo = 8;
    auto for_each_link = [&](auto&& link) {
        for (size_t g = 0; g < shared.group_count(); ++g) {
            const uint32_t b = shared.group_start[g], e = shared.group_start[g + 1];
            if (e - b <= kAllPairsUpTo) {
                for (uint32_t i = b; i < e; ++i)
                    for (uint32_t j = i + 1; j < e; ++j) link(shared.edges[i].triangle, shared.edges[j].triangle);
            } else {
                for (uint32_t i = b; i + 1 < e; ++i) link(shared.edges[i].triangle, shared.edges[i + 1].triangle);
            }
        }
    };
    TriangleAdjacency adj;
    adj.start.assign(triangle_count + 1, 0);
    for_each_link([&](uint32_t a, uint32_t b) {
        ++adj.start[a + 1];
        ++adj.start[b + 1];
    });
    std::partial_sum(adj.start.begin(), adj.start.end(), adj.start.begin());
    adj.neighbours.resize(adj.start.back());
    std::vector<uint32_t> fill(adj.start.begin(), adj.start.end() - 1);
    for_each_link([&](uint32_t a, uint32_t b) {
        adj.neighbours[fill[a]++] = b;
        adj.neighbours[fill[b]++] = a;
    });
    return adj;
}

SharedEdges scene_shared_edges(const Scene& scene) {
    const auto weld = atlas_detail::weld_positions(scene.positions, atlas_detail::weld_tolerance(scene));
    return atlas_detail::find_shared_edges(scene.triangles, weld);
}

// The world length of every chart's border: triangle edges that no other
// triangle of the same chart shares (a chart's outline, and the rims of its
// holes); charts with `unlit` set (by chart id; empty: none) left out.
double chart_border_length(const Scene& scene, const SharedEdges& shared, const std::vector<uint32_t>& triangle_chart,
                           const std::vector<uint8_t>& unlit = {}) {
    auto counts = [&](uint32_t t) { return unlit.empty() || !unlit[triangle_chart[t]]; };
    auto length = [&](EdgeRef e) {
        const glm::uvec3 t = scene.triangles[e.triangle];
        return double(glm::distance(scene.positions[t[e.edge]], scene.positions[t[(e.edge + 1) % 3]]));
    };
    double border = 0.0;
    for (uint32_t t = 0; t < scene.triangles.size(); ++t)
        for (uint32_t k = 0; k < 3 && counts(t); ++k) border += length({t, k});
    for (size_t g = 0; g < shared.group_count(); ++g)
        for (uint32_t i = shared.group_start[g]; i < shared.group_start[g + 1]; ++i)
            for (uint32_t j = shared.group_start[g]; j < shared.group_start[g + 1]; ++j)
                if (j != i && counts(shared.edges[i].triangle) &&
                    triangle_chart[shared.edges[j].triangle] == triangle_chart[shared.edges[i].triangle]) {
                    border -= length(shared.edges[i]);
                    break;
                }
    return std::max(border, 0.0);
}

// ---------------------------------------------------------------------------
// Chart segmentation.

struct PlaneBasis {
    glm::dvec3 origin, normal, tangent, bitangent;
    explicit PlaneBasis(glm::dvec3 o, glm::dvec3 n) : origin(o), normal(n) {
        const glm::dvec3 helper = std::abs(n.x) < 0.9 ? glm::dvec3(1, 0, 0) : glm::dvec3(0, 1, 0);
        tangent = glm::normalize(glm::cross(n, helper));
        bitangent = glm::cross(n, tangent);
    }
    glm::dvec2 project(const glm::vec3& p) const {
        const glm::dvec3 d = glm::dvec3(p) - origin;
        return {glm::dot(d, tangent), glm::dot(d, bitangent)};
    }
};

double cross2(glm::dvec2 a, glm::dvec2 b) { return a.x * b.y - a.y * b.x; }

double signed_area2(const Tri2& t) { return cross2(t[1] - t[0], t[2] - t[0]); }

// True when the interiors of two triangles overlap by more than a sliver
// (separating axis test). Triangles that only share an edge or a vertex do not.
bool interiors_overlap(const Tri2& a, const Tri2& b) {
    double scale = 0.0;
    for (int k = 0; k < 3; ++k)
        scale = std::max({scale, glm::length(a[(k + 1) % 3] - a[k]), glm::length(b[(k + 1) % 3] - b[k])});
    const double eps = 1e-6 * scale;
    for (const Tri2* tri : {&a, &b})
        for (int k = 0; k < 3; ++k) {
            const glm::dvec2 edge = (*tri)[(k + 1) % 3] - (*tri)[k];
            const double len = glm::length(edge);
            if (!(len > 0.0)) continue;
            const glm::dvec2 axis(-edge.y / len, edge.x / len);
            double a_lo = 1e300, a_hi = -1e300, b_lo = 1e300, b_hi = -1e300;
            for (int i = 0; i < 3; ++i) {
                a_lo = std::min(a_lo, glm::dot(a[i], axis));
                a_hi = std::max(a_hi, glm::dot(a[i], axis));
                b_lo = std::min(b_lo, glm::dot(b[i], axis));
                b_hi = std::max(b_hi, glm::dot(b[i], axis));
            }
            if (a_hi <= b_lo + eps || b_hi <= a_lo + eps) return false;
        }
    return true;
}

// The projected triangles of the chart being grown, bucketed in a uniform
// grid, so that a candidate is tested only against triangles near it.
class OverlapGrid {
public:
    void reset(double cell) {
        cell_ = cell;
        if (cells_.bucket_count() > 4096) cells_ = {};  // clear() would walk every old bucket per chart
        else cells_.clear();
        triangles_.clear();
        wide_.clear();
    }
    bool overlaps_any(const Tri2& tri) const {
        for (uint32_t i : wide_)
            if (interiors_overlap(tri, triangles_[i])) return true;
        bool hit = false;
        for_cells(tri, [&](uint64_t key) {
            if (hit) return;
            auto it = cells_.find(key);
            if (it == cells_.end()) return;
            for (uint32_t i : it->second)
                if (interiors_overlap(tri, triangles_[i])) {
                    hit = true;
                    return;
                }
        });
        return hit;
    }
    void insert(const Tri2& tri) {
        const auto id = uint32_t(triangles_.size());
        triangles_.push_back(tri);
        // A long sliver would fill thousands of cells; such triangles are few
        // and are tested against every candidate instead.
        if (cell_span(tri) > 1024) {
            wide_.push_back(id);
            return;
        }
        for_cells(tri, [&](uint64_t key) { cells_[key].push_back(id); });
    }

private:
    glm::i64vec4 cell_range(const Tri2& tri) const {
        glm::dvec2 lo = glm::min(glm::min(tri[0], tri[1]), tri[2]);
        glm::dvec2 hi = glm::max(glm::max(tri[0], tri[1]), tri[2]);
        // Clamped before the conversion (a hostile scene's coordinates
        // overflowed int64 here: found by fuzzing); the loader also refuses
        // scenes beyond LoadLimits::max_coordinate.
        auto cell = [&](double v) {
            double c = std::floor(v / cell_);
            if (!(c > -1e15)) c = -1e15;  // NaN too
            if (!(c < 1e15)) c = 1e15;
            return int64_t(c);
        };
        return {cell(lo.x), cell(lo.y), cell(hi.x), cell(hi.y)};
    }
    int64_t cell_span(const Tri2& tri) const {
        auto r = cell_range(tri);
        return (r.z - r.x + 1) * (r.w - r.y + 1);
    }
    template <typename F>
    void for_cells(const Tri2& tri, F&& visit) const {
        auto r = cell_range(tri);
        if ((r.z - r.x + 1) * (r.w - r.y + 1) > 1024) {  // only reachable from overlaps_any for a wide candidate
            for (const auto& [key, ids] : cells_) visit(key);
            return;
        }
        for (int64_t y = r.y; y <= r.w; ++y)
            for (int64_t x = r.x; x <= r.z; ++x) visit((uint64_t(uint32_t(int32_t(x))) << 32) | uint32_t(int32_t(y)));
    }

    double cell_ = 1.0;
    std::unordered_map<uint64_t, std::vector<uint32_t>> cells_;
    std::vector<Tri2> triangles_;
    std::vector<uint32_t> wide_;
};

struct Chart {
    std::vector<uint32_t> triangles;
    PlaneBasis plane;
};

Tri2 project_triangle(const Scene& scene, const PlaneBasis& plane, uint32_t t) {
    const glm::uvec3& tri = scene.triangles[t];
    return {plane.project(scene.positions[tri.x]), plane.project(scene.positions[tri.y]),
            plane.project(scene.positions[tri.z])};
}

// Grows charts from the largest unassigned triangle outwards across shared
// edges. A neighbour joins when its normal is within the angle limit of the
// seed's and its projection onto the seed's plane overlaps no triangle already
// in the chart, so every chart is a flat, non-overlapping map of its triangles.
std::vector<Chart> segment_charts(const Scene& scene, const TriangleAdjacency& adjacency, float max_angle_degrees,
                                  std::vector<uint32_t>& triangle_chart) {
    const size_t n = scene.triangles.size();
    std::vector<float> area(n);
    std::vector<glm::vec3> normal(n);
    for (size_t t = 0; t < n; ++t) {
        area[t] = scene.triangle_area(t);
        normal[t] = scene.geometric_normal(t);
    }
    std::vector<uint32_t> seeds(n);
    std::iota(seeds.begin(), seeds.end(), 0u);
    std::stable_sort(seeds.begin(), seeds.end(), [&](uint32_t a, uint32_t b) { return area[a] > area[b]; });

    const float min_cos = std::cos(glm::radians(max_angle_degrees));
    triangle_chart.assign(n, kNone);
    std::vector<Chart> charts;
    OverlapGrid grid;
    std::vector<uint32_t> frontier;

    for (uint32_t seed : seeds) {
        if (triangle_chart[seed] != kNone) continue;
        const auto chart_id = uint32_t(charts.size());
        const glm::vec3 seed_normal = glm::length(normal[seed]) > 0.0f ? normal[seed] : glm::vec3(0, 0, 1);
        charts.push_back(
            {{}, PlaneBasis(glm::dvec3(scene.positions[scene.triangles[seed].x]), glm::dvec3(seed_normal))});
        Chart& chart = charts.back();
        // Every triangle still unassigned is no larger than the seed, so cells
        // the seed's size hold a few triangles each.
        grid.reset(std::max(1.5 * std::sqrt(double(area[seed])), 1e-9));

        auto add = [&](uint32_t t) {
            triangle_chart[t] = chart_id;
            chart.triangles.push_back(t);
            if (area[t] > 0.0f) grid.insert(project_triangle(scene, chart.plane, t));
            frontier.push_back(t);
        };
        auto accepts = [&](uint32_t t) {
            if (area[t] <= 0.0f) return true;  // degenerate: adds no area, goes with its neighbour
            if (glm::dot(normal[t], seed_normal) < min_cos) return false;
            return !grid.overlaps_any(project_triangle(scene, chart.plane, t));
        };

        add(seed);
        while (!frontier.empty()) {
            const uint32_t t = frontier.back();
            frontier.pop_back();
            for (uint32_t i = adjacency.start[t]; i < adjacency.start[t + 1]; ++i) {
                const uint32_t u = adjacency.neighbours[i];
                if (triangle_chart[u] == kNone && accepts(u)) add(u);
            }
        }
    }
    return charts;
}

// ---------------------------------------------------------------------------
// Chart layout: each chart's triangles in its own 2D frame, in metres.

struct ChartShape {
    glm::dvec2 size{0.0};  // extent of the chart in its frame (metres, area-corrected)
};

std::vector<glm::dvec2> convex_hull(std::vector<glm::dvec2> points) {
    std::sort(points.begin(), points.end(), [](auto a, auto b) { return a.x != b.x ? a.x < b.x : a.y < b.y; });
    points.erase(std::unique(points.begin(), points.end()), points.end());
    if (points.size() < 3) return points;
    std::vector<glm::dvec2> hull(2 * points.size());
    size_t k = 0;
    for (size_t i = 0; i < points.size(); ++i) {  // lower hull
        while (k >= 2 && cross2(hull[k - 1] - hull[k - 2], points[i] - hull[k - 2]) <= 0) --k;
        hull[k++] = points[i];
    }
    for (size_t i = points.size() - 1, lower = k + 1; i-- > 0;) {  // upper hull
        while (k >= lower && cross2(hull[k - 1] - hull[k - 2], points[i] - hull[k - 2]) <= 0) --k;
        hull[k++] = points[i];
    }
    hull.resize(k - 1);
    return hull;
}

// The unit direction whose bounding rectangle of `hull` has the least area
// (one rectangle side is parallel to a hull edge, so the hull edges are the
// candidates; at most 256 of them are tried).
glm::dvec2 min_area_rect_direction(const std::vector<glm::dvec2>& hull) {
    glm::dvec2 best(1.0, 0.0);
    if (hull.size() < 3) {
        if (hull.size() == 2 && glm::length(hull[1] - hull[0]) > 0.0) best = glm::normalize(hull[1] - hull[0]);
        return best;
    }
    double best_area = 1e300;
    const size_t stride = std::max<size_t>(1, hull.size() / 256);
    for (size_t i = 0; i < hull.size(); i += stride) {
        const glm::dvec2 edge = hull[(i + 1) % hull.size()] - hull[i];
        const double len = glm::length(edge);
        if (!(len > 0.0)) continue;
        const glm::dvec2 d = edge / len, p(-d.y, d.x);
        double lo_d = 1e300, hi_d = -1e300, lo_p = 1e300, hi_p = -1e300;
        for (const glm::dvec2& q : hull) {
            lo_d = std::min(lo_d, glm::dot(q, d));
            hi_d = std::max(hi_d, glm::dot(q, d));
            lo_p = std::min(lo_p, glm::dot(q, p));
            hi_p = std::max(hi_p, glm::dot(q, p));
        }
        const double a = (hi_d - lo_d) * (hi_p - lo_p);
        if (a < best_area) {
            best_area = a;
            best = d;
        }
    }
    return best;
}

// Writes the chart's corner coordinates into `corners` (metres, origin at the
// chart's bounding-rectangle corner, wider than tall) and returns its size.
// The projection is scaled so the chart's 2D area equals its world area: the
// texel density is then exact for every chart, flat or gently curved.
ChartShape lay_out_chart(const Scene& scene, const Chart& chart, std::vector<Tri2>& corners) {
    double world_area = 0.0, projected_area = 0.0;
    std::vector<glm::dvec2> points;
    points.reserve(chart.triangles.size() * 3);
    for (uint32_t t : chart.triangles) {
        corners[t] = project_triangle(scene, chart.plane, t);
        world_area += scene.triangle_area(t);
        projected_area += 0.5 * std::abs(signed_area2(corners[t]));
        points.insert(points.end(), corners[t].begin(), corners[t].end());
    }
    const glm::dvec2 d = min_area_rect_direction(convex_hull(points));
    const glm::dvec2 p(-d.y, d.x);
    const double scale = projected_area > 0.0 ? std::sqrt(world_area / projected_area) : 1.0;

    glm::dvec2 lo(1e300), hi(-1e300);
    for (uint32_t t : chart.triangles)
        for (glm::dvec2& c : corners[t]) {
            c = scale * glm::dvec2(glm::dot(c, d), glm::dot(c, p));
            lo = glm::min(lo, c);
            hi = glm::max(hi, c);
        }
    const bool turn = (hi.y - lo.y) > (hi.x - lo.x);  // wide charts stack better on a skyline
    for (uint32_t t : chart.triangles)
        for (glm::dvec2& c : corners[t]) {
            c -= lo;
            if (turn) c = glm::dvec2(c.y, c.x);
        }
    glm::dvec2 size = hi - lo;
    if (turn) size = glm::dvec2(size.y, size.x);
    return {size};
}

// ---------------------------------------------------------------------------
// Packing.

// A chart's rectangle in whole texels: its extent at the density, rounded up
// (at least one texel, so a chart smaller than a texel still owns one).
glm::ivec2 chart_rect(const ChartShape& shape, double density) {
    // Clamped before the conversion: a chart of a hostile scene (coordinates
    // of 1e21 m, found by fuzzing) would overflow int; any side this large
    // fails to pack anyway.
    constexpr double kLargest = 1 << 30;
    auto side = [&](double metres) {
        const double texels = std::ceil(metres * density - 1e-9);
        return std::max(1, int(std::isfinite(texels) ? std::min(texels, kLargest) : kLargest));
    };
    return {side(shape.size.x), side(shape.size.y)};
}

// Bottom-left skyline packing: each rectangle goes where its top edge ends
// lowest. Rectangles are `padding` texels apart; the padding after the last
// one in a row or column may hang over the atlas edge.
class SkylinePacker {
public:
    SkylinePacker(int width, int height, int padding) : limit_(width + padding, height + padding), padding_(padding) {
        skyline_.push_back({0, 0, limit_.x});
    }
    std::optional<glm::ivec2> place(glm::ivec2 rect) {
        const int w = rect.x + padding_, h = rect.y + padding_;
        int best_y = INT32_MAX;
        size_t best_i = 0;
        for (size_t i = 0; i < skyline_.size(); ++i) {
            const int x = skyline_[i].x;
            if (x + w > limit_.x) break;
            int y = 0;
            for (size_t j = i, covered = 0; covered < size_t(w); ++j) {
                y = std::max(y, skyline_[j].y);
                covered += size_t(skyline_[j].x + skyline_[j].width - std::max(skyline_[j].x, x));
            }
            if (y + h <= limit_.y && y < best_y) {
                best_y = y;
                best_i = i;
            }
        }
        if (best_y == INT32_MAX) return std::nullopt;
        const glm::ivec2 at(skyline_[best_i].x, best_y);
        raise(best_i, at.x, w, best_y + h);
        return at;
    }

private:
    struct Segment {
        int x, y, width;
    };
    void raise(size_t i, int x, int w, int top) {
        skyline_.insert(skyline_.begin() + std::ptrdiff_t(i), {x, top, w});
        for (size_t k = i + 1; k < skyline_.size();) {
            const int overlap = x + w - skyline_[k].x;
            if (overlap <= 0) break;
            if (skyline_[k].width <= overlap) {
                skyline_.erase(skyline_.begin() + std::ptrdiff_t(k));
                continue;
            }
            skyline_[k].x += overlap;
            skyline_[k].width -= overlap;
            break;
        }
        for (size_t k = 0; k + 1 < skyline_.size();) {  // merge equal heights
            if (skyline_[k].y == skyline_[k + 1].y) {
                skyline_[k].width += skyline_[k + 1].width;
                skyline_.erase(skyline_.begin() + std::ptrdiff_t(k + 1));
            } else {
                ++k;
            }
        }
    }
    glm::ivec2 limit_;
    int padding_;
    std::vector<Segment> skyline_;
};

// Top-left texel of every chart's rectangle, or nothing if they do not fit.
std::optional<std::vector<glm::ivec2>> pack_charts(const std::vector<ChartShape>& shapes, double density, int width,
                                                   int height, int padding) {
    std::vector<glm::ivec2> rects(shapes.size());
    for (size_t c = 0; c < shapes.size(); ++c) rects[c] = chart_rect(shapes[c], density);
    std::vector<uint32_t> order(shapes.size());
    std::iota(order.begin(), order.end(), 0u);
    std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) {
        return rects[a].y != rects[b].y ? rects[a].y > rects[b].y : rects[a].x > rects[b].x;
    });
    SkylinePacker packer(width, height, padding);
    std::vector<glm::ivec2> at(shapes.size());
    for (uint32_t c : order) {
        auto where = packer.place(rects[c]);
        if (!where) return std::nullopt;
        at[c] = *where;
    }
    return at;
}

// Texels the packed charts would take, padding included (for first guesses).
double packed_area(const std::vector<ChartShape>& shapes, double density, int padding) {
    double sum = 0.0;
    for (const ChartShape& s : shapes) {
        const glm::ivec2 r = chart_rect(s, density);
        sum += double(r.x + padding) * double(r.y + padding);
    }
    return sum;
}

// The density at which the packed charts take about `fill` of the atlas.
double estimate_density(const std::vector<ChartShape>& shapes, double atlas_texels, int padding, double fill) {
    double lo = 0.0, hi = 1.0;
    while (packed_area(shapes, hi, padding) < fill * atlas_texels && hi < 1e12) hi *= 2.0;
    for (int i = 0; i < 40; ++i) {
        const double mid = 0.5 * (lo + hi);
        (packed_area(shapes, mid, padding) < fill * atlas_texels ? lo : hi) = mid;
    }
    return lo;
}

struct Packing {
    int size = 0;  // square atlas side
    double density = 0.0;
    std::vector<glm::ivec2> at;
};

// The largest density (at most `density_cap`, if set) whose charts fit a
// size x size atlas, found by bisection over packing attempts.
std::optional<Packing> pack_at_resolution(const std::vector<ChartShape>& shapes, int size, int padding,
                                          double density_cap) {
    auto attempt = [&](double d) { return pack_charts(shapes, d, size, size, padding); };
    // Never 0: at a guess of 0 every chart is one texel, that "fits", and
    // growing hi = 0 * 1.25 would never end (an atlas just big enough for
    // its charts' padding used to hang here).
    double guess = std::max(estimate_density(shapes, double(size) * size, padding, 0.9), 1e-9);
    if (density_cap > 0.0) guess = std::min(guess, density_cap);

    std::optional<std::vector<glm::ivec2>> best;
    double lo = 0.0, hi = 0.0;
    if (auto at = attempt(guess)) {
        best = std::move(at);
        lo = guess;
        if (density_cap > 0.0 && guess >= density_cap) return Packing{size, lo, std::move(*best)};
        hi = density_cap > 0.0 ? density_cap : guess * 1.25;
        if (density_cap <= 0.0)
            while (auto more = attempt(hi)) {
                best = std::move(more);
                lo = hi;
                hi *= 1.25;
            }
        else if (auto at_cap = attempt(hi)) return Packing{size, hi, std::move(*at_cap)};
    } else {
        hi = guess;
        lo = guess;
        // Down to one texel per chart (the density smallest_atlas_resolution
        // packs at); density 0 would collapse every chart to a point.
        for (int tries = 0; tries < 120 && !best && lo > 1e-12; ++tries) {
            lo = std::max(lo * 0.7, 1e-12);
            best = attempt(lo);
            if (!best) hi = lo;
        }
        if (!best) return std::nullopt;  // not even one texel per chart fits
    }
    for (int i = 0; i < 10 && hi > lo * 1.005; ++i) {
        const double mid = 0.5 * (lo + hi);
        if (auto at = attempt(mid)) {
            best = std::move(at);
            lo = mid;
        } else hi = mid;
    }
    return Packing{size, lo, std::move(*best)};
}

Packing pack_atlas(const std::vector<ChartShape>& shapes, const AtlasOptions& options) {
    const int padding = std::max(0, options.padding);
    auto too_small = [&](int size) {
        return AtlasDoesNotFit("atlas: " + std::to_string(shapes.size()) + " charts do not fit a " +
                               std::to_string(size) + "x" + std::to_string(size) +
                               " atlas even at one texel each; raise the resolution");
    };
    if (options.resolution > 0 || options.texel_density <= 0.0f) {
        const int size = options.resolution > 0 ? options.resolution : kDefaultResolution;
        auto packing = pack_at_resolution(shapes, size, padding, options.texel_density);
        if (!packing) throw too_small(size);
        return *packing;
    }
    // Density given: the smallest square that holds the charts, up to the cap.
    const double density = options.texel_density;
    int size = std::max(1, int(std::ceil(std::sqrt(packed_area(shapes, density, padding) / 0.85))));
    while (size < options.max_resolution) {
        if (auto at = pack_charts(shapes, density, size, size, padding)) return Packing{size, density, std::move(*at)};
        size = std::min(options.max_resolution, int(std::ceil(size * 1.05)) + 1);
    }
    auto packing = pack_at_resolution(shapes, options.max_resolution, padding, density);
    if (!packing) throw too_small(options.max_resolution);
    return *packing;
}

double border_fraction(double border_length, double area, double density) {
    return area > 0.0 && density > 0.0 ? border_length / (2.0 * area * density) : 0.0;
}

// Options with the texel density chosen from the scene when neither a
// resolution nor a density is given and max_border_fraction is: the density
// at which border_fraction is max_border_fraction, the atlas capped at
// auto_max_resolution. Unchanged otherwise.
AtlasOptions with_density_from_scene(const AtlasOptions& options, double border_length, double area) {
    if (options.resolution > 0 || options.texel_density > 0.0f || options.max_border_fraction <= 0.0f ||
        border_length <= 0.0 || area <= 0.0)
        return options;
    AtlasOptions chosen = options;
    chosen.texel_density = float(border_length / (2.0 * area * double(options.max_border_fraction)));
    chosen.max_resolution = std::min(options.max_resolution, options.auto_max_resolution);
    return chosen;
}

// pack_atlas, the density chosen from the scene where with_density_from_scene
// chooses one and it is finer than the default atlas filled: an auto atlas
// is never coarser than kDefaultResolution² (sets from_scene when finer).
Packing pack_atlas_for_scene(const std::vector<ChartShape>& shapes, const AtlasOptions& options, double border_length,
                             double area, bool& from_scene) {
    const AtlasOptions chosen = with_density_from_scene(options, border_length, area);
    from_scene = false;
    if (chosen.texel_density == options.texel_density) return pack_atlas(shapes, options);
    auto filled = pack_at_resolution(shapes, kDefaultResolution, std::max(0, options.padding), 0.0);
    if (filled && filled->density >= chosen.texel_density) return *filled;
    from_scene = true;
    return pack_atlas(shapes, chosen);
}

// Lays the charts flagged in `unlit` out at kUnlitChartScale of their size
// (fewer texels for one black value); counts them in the report. Returns
// the area of the lit charts.
double shrink_unlit_charts(const Scene& scene, const std::vector<Chart>& charts, const std::vector<uint8_t>& unlit,
                           std::vector<ChartShape>& shapes, std::vector<Tri2>& corners, AtlasReport& report) {
    double lit = 0.0, dark = 0.0;
    for (size_t c = 0; c < charts.size(); ++c) {
        double area = 0.0;
        for (uint32_t t : charts[c].triangles) area += scene.triangle_area(t);
        if (unlit.empty() || !unlit[c]) {
            lit += area;
            continue;
        }
        dark += area;
        ++report.unlit_charts;
        shapes[c].size *= kUnlitChartScale;
        for (uint32_t t : charts[c].triangles)
            for (glm::dvec2& corner : corners[t]) corner *= kUnlitChartScale;
    }
    report.unlit_area_fraction = lit + dark > 0.0 ? dark / (lit + dark) : 0.0;
    return lit;
}

// ---------------------------------------------------------------------------
// Writing UVs: a vertex has one UV1, so a vertex used by triangles of several
// charts is split into one copy per chart.

uint32_t source_of(const Scene& scene, const PrimitiveInstance& inst, uint32_t v) {
    return scene.source_vertex.empty() ? v - inst.first_vertex : scene.source_vertex[v];
}

// Rebuilds the vertex arrays instance by instance: each instance keeps its
// own vertices in their order (so an unsplit instance is unchanged) and gets
// its split copies appended right after them, so its range stays contiguous.
void write_corner_uvs(Scene& scene, const std::vector<uint32_t>& triangle_chart, const CornerUVs& corner_uv) {
    std::vector<glm::vec3> positions, normals;
    std::vector<glm::vec2> uv0, uv1;
    std::vector<uint32_t> source;
    positions.reserve(scene.positions.size() * 5 / 4);
    auto copy_vertex = [&](uint32_t v, uint32_t src) {
        positions.push_back(scene.positions[v]);
        normals.push_back(scene.normals[v]);
        uv0.push_back(scene.uv0[v]);
        uv1.push_back(glm::vec2(0.0f));
        source.push_back(src);
    };

    for (PrimitiveInstance& inst : scene.instances) {
        const auto first = uint32_t(positions.size());
        for (uint32_t v = inst.first_vertex; v < inst.first_vertex + inst.vertex_count; ++v)
            copy_vertex(v, source_of(scene, inst, v));
        std::vector<uint32_t> first_chart(inst.vertex_count, kNone);
        std::unordered_map<uint64_t, uint32_t> copies;  // (local vertex, chart) -> new vertex
        for (uint32_t t = inst.first_triangle; t < inst.first_triangle + inst.triangle_count; ++t) {
            glm::uvec3& tri = scene.triangles[t];
            const uint32_t chart = triangle_chart[t];
            for (int k = 0; k < 3; ++k) {
                if (tri[k] < inst.first_vertex || tri[k] >= inst.first_vertex + inst.vertex_count)
                    throw std::logic_error("atlas: a triangle uses a vertex outside its primitive instance");
                const uint32_t local = tri[k] - inst.first_vertex;
                uint32_t out = first + local;
                if (first_chart[local] == kNone) {
                    first_chart[local] = chart;
                } else if (first_chart[local] != chart) {
                    auto [it, inserted] =
                        copies.try_emplace((uint64_t(local) << 32) | chart, uint32_t(positions.size()));
                    if (inserted) copy_vertex(tri[k], source_of(scene, inst, tri[k]));
                    out = it->second;
                }
                uv1[out] = corner_uv[t][size_t(k)];
                tri[k] = out;
            }
        }
        inst.first_vertex = first;
        inst.vertex_count = uint32_t(positions.size()) - first;
        inst.has_uv1 = true;
    }
    scene.positions = std::move(positions);
    scene.normals = std::move(normals);
    scene.uv0 = std::move(uv0);
    scene.uv1 = std::move(uv1);
    scene.source_vertex = std::move(source);
}

double total_world_area(const Scene& scene) {
    double sum = 0.0;
    for (size_t t = 0; t < scene.triangles.size(); ++t) sum += scene.triangle_area(t);
    return sum;
}

// Sum of |UV1 area| over triangles, in unit UV.
double total_uv1_area(const Scene& scene) {
    double sum = 0.0;
    for (const glm::uvec3& t : scene.triangles) {
        const glm::dvec2 a(scene.uv1[t.x]), b(scene.uv1[t.y]), c(scene.uv1[t.z]);
        sum += 0.5 * std::abs(cross2(b - a, c - a));
    }
    return sum;
}

double utilisation(const Scene& scene, int width, int height) {
    const std::vector<uint8_t> mask = coverage_mask(scene, width, height);
    return double(std::count(mask.begin(), mask.end(), uint8_t(1))) / (double(width) * double(height));
}

size_t count_uv_islands(const Scene& scene) {
    const std::vector<uint32_t> island = uv_island_of_triangle(scene);
    std::vector<uint8_t> is_island(scene.positions.size(), 0);
    for (uint32_t i : island) is_island[i] = 1;
    return size_t(std::count(is_island.begin(), is_island.end(), uint8_t(1)));
}

}  // namespace

std::vector<uint32_t> uv_island_of_triangle(const Scene& scene) {
    std::vector<uint32_t> parent(scene.positions.size());
    std::iota(parent.begin(), parent.end(), 0u);
    auto find = [&](uint32_t x) {
        while (parent[x] != x) x = parent[x] = parent[parent[x]];
        return x;
    };
    for (const glm::uvec3& t : scene.triangles) {
        parent[find(t.y)] = find(t.x);
        parent[find(t.z)] = find(t.x);
    }
    std::vector<uint32_t> island(scene.triangles.size());
    for (size_t t = 0; t < island.size(); ++t) island[t] = find(scene.triangles[t].x);
    return island;
}

// ---------------------------------------------------------------------------

AtlasReport generate_lightmap_uvs(Scene& scene, const AtlasOptions& options) {
    AtlasReport report;
    report.generated = true;
    const SharedEdges shared = scene_shared_edges(scene);
    std::vector<Chart> charts = segment_charts(scene, triangle_adjacency(scene.triangles.size(), shared),
                                               options.max_chart_angle_degrees, report.triangle_chart);

    std::vector<Tri2> corners(scene.triangles.size());
    std::vector<ChartShape> shapes(charts.size());
    for (size_t c = 0; c < charts.size(); ++c) shapes[c] = lay_out_chart(scene, charts[c], corners);

    std::vector<uint8_t> unlit;
    if (options.find_unlit_charts) unlit = options.find_unlit_charts(report.triangle_chart, charts.size());
    const double lit_area = shrink_unlit_charts(scene, charts, unlit, shapes, corners, report);
    const double border = chart_border_length(scene, shared, report.triangle_chart, unlit);
    const Packing packing = pack_atlas_for_scene(shapes, options, border, lit_area, report.density_from_scene);
    const double w = packing.size, h = packing.size;
    CornerUVs corner_uv(scene.triangles.size());
    for (size_t c = 0; c < charts.size(); ++c) {
        // Centre the chart in its whole-texel rectangle.
        const glm::dvec2 extent = shapes[c].size * packing.density;
        const glm::dvec2 rect(chart_rect(shapes[c], packing.density));
        const glm::dvec2 rect_lo(packing.at[c]), rect_hi = rect_lo + rect;
        const glm::dvec2 origin = rect_lo + glm::max(0.5 * (rect - extent), 0.0);
        for (uint32_t t : charts[c].triangles)
            for (int k = 0; k < 3; ++k) {
                // The clamp only removes rounding (chart_rect tolerates 1e-9 texel).
                const glm::dvec2 pixel = glm::clamp(origin + corners[t][size_t(k)] * packing.density, rect_lo, rect_hi);
                corner_uv[t][size_t(k)] = glm::vec2(pixel.x / w, pixel.y / h);
            }
    }
    write_corner_uvs(scene, report.triangle_chart, corner_uv);

    report.width = report.height = packing.size;
    report.texel_density = float(packing.density);
    report.border_fraction = border_fraction(border, lit_area, packing.density);
    report.charts = charts.size();
    report.utilisation = utilisation(scene, report.width, report.height);
    return report;
}

int smallest_atlas_resolution(const Scene& scene, const AtlasOptions& options) {
    const TriangleAdjacency adjacency = triangle_adjacency(scene.triangles.size(), scene_shared_edges(scene));
    std::vector<uint32_t> triangle_chart;
    const std::vector<Chart> charts = segment_charts(scene, adjacency, options.max_chart_angle_degrees, triangle_chart);
    std::vector<Tri2> corners(scene.triangles.size());
    std::vector<ChartShape> shapes(charts.size());
    for (size_t c = 0; c < charts.size(); ++c) shapes[c] = lay_out_chart(scene, charts[c], corners);
    // One texel per chart: a density so small that every chart rounds up to one.
    constexpr double kOneTexel = 1e-12;
    const int padding = std::max(0, options.padding);
    auto fits = [&](int size) { return pack_charts(shapes, kOneTexel, size, size, padding).has_value(); };
    if (!fits(options.max_resolution)) return 0;
    int lo = 1, hi = options.max_resolution;  // fits(hi); find the smallest that fits
    while (lo < hi) {
        const int mid = lo + (hi - lo) / 2;
        if (fits(mid)) hi = mid;
        else lo = mid + 1;
    }
    return hi;
}

AtlasReport use_existing_lightmap_uvs(const Scene& scene, const AtlasOptions& options) {
    AtlasReport report;
    const double world = total_world_area(scene), uv = total_uv1_area(scene);
    const double border = chart_border_length(scene, scene_shared_edges(scene), uv_island_of_triangle(scene));
    const AtlasOptions chosen = with_density_from_scene(options, border, world);
    int size = kDefaultResolution;
    if (chosen.resolution > 0) {
        size = chosen.resolution;
    } else if (chosen.texel_density > 0.0f && uv > 0.0) {
        // uv x size² texels cover `world` m² at density²: size = density x sqrt(world / uv).
        const double wanted = std::ceil(double(chosen.texel_density) * std::sqrt(world / uv));
        size = int(std::clamp(wanted, 1.0, double(chosen.max_resolution)));
        // From the scene: never coarser than the default (see pack_atlas_for_scene).
        report.density_from_scene = chosen.texel_density != options.texel_density && size > kDefaultResolution;
        if (chosen.texel_density != options.texel_density) size = std::max(size, kDefaultResolution);
    }
    report.width = report.height = size;
    report.texel_density = world > 0.0 ? float(std::sqrt(uv * double(size) * double(size) / world)) : 0.0f;
    report.border_fraction = border_fraction(border, world, report.texel_density);
    report.charts = count_uv_islands(scene);
    report.utilisation = utilisation(scene, size, size);
    return report;
}

AtlasReport prepare_lightmap_atlas(Scene& scene, const AtlasOptions& options) {
    return scene.all_have_lightmap_uvs() ? use_existing_lightmap_uvs(scene, options)
                                         : generate_lightmap_uvs(scene, options);
}

// ---------------------------------------------------------------------------
// The thesis's triangle-pair atlas.

namespace {

struct TrianglePair {
    uint32_t a = kNone, b = kNone;  // b == kNone: a lone triangle
    double area = 0.0;
    uint32_t triangle_count() const { return b == kNone ? 1u : 2u; }
};

// Algorithm C.1: each triangle is paired with an unassigned neighbour sharing
// an edge, or left alone; pairs sorted by area, smallest first.
std::vector<TrianglePair> pair_triangles(const Scene& scene, const TriangleAdjacency& adjacency) {
    std::vector<uint8_t> assigned(scene.triangles.size(), 0);
    std::vector<TrianglePair> pairs;
    for (uint32_t t = 0; t < scene.triangles.size(); ++t) {
        if (assigned[t]) continue;
        assigned[t] = 1;
        TrianglePair pair{t, kNone, scene.triangle_area(t)};
        for (uint32_t i = adjacency.start[t]; i < adjacency.start[t + 1]; ++i) {
            const uint32_t u = adjacency.neighbours[i];
            if (assigned[u]) continue;
            assigned[u] = 1;
            pair.b = u;
            pair.area += scene.triangle_area(u);
            break;
        }
        pairs.push_back(pair);
    }
    std::stable_sort(pairs.begin(), pairs.end(), [](const auto& x, const auto& y) { return x.area < y.area; });
    return pairs;
}

// Maps a pair onto its cell (pixels): the shared edge on the diagonal from
// (x0,y0) to (x1,y1), one triangle on each side of it.
void map_pair_to_cell(const Scene& scene, const std::vector<uint32_t>& weld, const TrianglePair& pair, glm::dvec4 cell,
                      glm::dvec2 atlas_size, CornerUVs& corner_uv) {
    const glm::dvec2 lo(cell.x, cell.y), hi(cell.z, cell.w);
    const glm::dvec2 s0 = lo, s1 = hi, opposite_a(hi.x, lo.y), opposite_b(lo.x, hi.y);
    auto uv = [&](glm::dvec2 p) { return glm::vec2(p / atlas_size); };
    const glm::uvec3& ta = scene.triangles[pair.a];
    if (pair.b == kNone) {
        corner_uv[pair.a] = {uv(s0), uv(opposite_a), uv(s1)};
        return;
    }
    const glm::uvec3& tb = scene.triangles[pair.b];
    // The edge of a whose welded endpoints both appear in b.
    auto in_b = [&](uint32_t v) { return weld[v] == weld[tb.x] || weld[v] == weld[tb.y] || weld[v] == weld[tb.z]; };
    int k = 0;
    while (k < 3 && !(in_b(ta[k]) && in_b(ta[(k + 1) % 3]))) ++k;
    if (k == 3) k = 0;
    const uint32_t shared0 = weld[ta[k]], shared1 = weld[ta[(k + 1) % 3]];
    corner_uv[pair.a][size_t(k)] = uv(s0);
    corner_uv[pair.a][size_t((k + 1) % 3)] = uv(s1);
    corner_uv[pair.a][size_t((k + 2) % 3)] = uv(opposite_a);
    for (size_t j = 0; j < 3; ++j) {
        const uint32_t w = weld[tb[int(j)]];
        corner_uv[pair.b][j] = uv(w == shared0 ? s0 : w == shared1 ? s1 : opposite_b);
    }
}

}  // namespace

AtlasReport generate_triangle_pair_uvs(Scene& scene, const AtlasOptions& options) {
    AtlasReport report;
    report.generated = true;
    const double world = total_world_area(scene);
    int size = kDefaultResolution;
    if (options.resolution > 0) size = options.resolution;
    else if (options.texel_density > 0.0f)
        size = int(std::clamp(std::ceil(double(options.texel_density) * std::sqrt(world)), 1.0,
                              double(options.max_resolution)));

    const auto weld = atlas_detail::weld_positions(scene.positions, atlas_detail::weld_tolerance(scene));
    const TriangleAdjacency adjacency =
        triangle_adjacency(scene.triangles.size(), atlas_detail::find_shared_edges(scene.triangles, weld));
    const std::vector<TrianglePair> pairs = pair_triangles(scene, adjacency);

    // Prefix sums of triangle counts and areas for the balance search.
    std::vector<double> count_prefix(pairs.size() + 1, 0.0), area_prefix(pairs.size() + 1, 0.0);
    for (size_t i = 0; i < pairs.size(); ++i) {
        count_prefix[i + 1] = count_prefix[i] + pairs[i].triangle_count();
        area_prefix[i + 1] = area_prefix[i] + pairs[i].area;
    }

    // Algorithm C.2, with an explicit stack: split [begin, end) where
    // K x (left triangle share) + (left area share) first reaches the right's.
    constexpr double K = 1.5;
    struct Task {
        size_t begin, end;
        glm::dvec4 cell;
    };
    std::vector<Task> stack{{0, pairs.size(), glm::dvec4(0, 0, size, size)}};
    CornerUVs corner_uv(scene.triangles.size());
    report.triangle_chart.assign(scene.triangles.size(), kNone);
    const glm::dvec2 atlas_size(size, size);
    while (!stack.empty()) {
        const Task task = stack.back();
        stack.pop_back();
        if (task.end - task.begin == 1) {
            const TrianglePair& pair = pairs[task.begin];
            // Carr and Hart: pull the pair half a texel inside its cell.
            const double inset = std::min(0.5, 0.25 * std::min(task.cell.z - task.cell.x, task.cell.w - task.cell.y));
            const glm::dvec4 cell = task.cell + glm::dvec4(inset, inset, -inset, -inset);
            map_pair_to_cell(scene, weld, pair, cell, atlas_size, corner_uv);
            report.triangle_chart[pair.a] = uint32_t(task.begin);
            if (pair.b != kNone) report.triangle_chart[pair.b] = uint32_t(task.begin);
            continue;
        }
        const double all_count = count_prefix[task.end] - count_prefix[task.begin];
        const double all_area = std::max(area_prefix[task.end] - area_prefix[task.begin], 1e-300);
        auto left_heavier = [&](size_t split) {  // left = [begin, split)
            const double lc = (count_prefix[split] - count_prefix[task.begin]) / all_count;
            const double la = (area_prefix[split] - area_prefix[task.begin]) / all_area;
            return K * lc + la >= K * (1.0 - lc) + (1.0 - la);
        };
        size_t lo = task.begin + 1, hi = task.end - 1;  // the split point lies in [lo, hi]
        while (lo < hi) {
            const size_t mid = (lo + hi) / 2;
            if (left_heavier(mid)) hi = mid;
            else lo = mid + 1;
        }
        const glm::dvec4 c = task.cell;
        glm::dvec4 left = c, right = c;
        if (c.z - c.x >= c.w - c.y) left.z = right.x = 0.5 * (c.x + c.z);
        else left.w = right.y = 0.5 * (c.y + c.w);
        stack.push_back({task.begin, lo, left});
        stack.push_back({lo, task.end, right});
    }
    write_corner_uvs(scene, report.triangle_chart, corner_uv);

    report.width = report.height = size;
    report.texel_density = world > 0.0 ? float(std::sqrt(total_uv1_area(scene) * double(size) * size / world)) : 0.0f;
    report.charts = pairs.size();
    report.utilisation = utilisation(scene, size, size);
    return report;
}

}  // namespace lf
