#include "atlas/atlas.h"

#include "atlas/mesh_topology.h"
#include "atlas/texel_samples.h"
#include "util/parallel.h"
#include "util/math.h"

#include <glm/gtc/constants.hpp>

#include <algorithm>
#include <array>
#include <bit>
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
        boxes_.clear();
        wide_.clear();
    }
    bool overlaps_any(const Tri2& tri) const {
        const Box box = box_of(tri);
        // Boxes apart (touching included) are triangles apart: the separating
        // axis test would find an edge that separates them too, so this
        // only skips the work, never changes the answer.
        const auto overlaps = [&](uint32_t i) {
            return boxes_overlap(box, boxes_[i]) && interiors_overlap(tri, triangles_[i]);
        };
        for (uint32_t i : wide_)
            if (overlaps(i)) return true;
        bool hit = false;
        for_cells(tri, [&](uint64_t key) {
            if (hit) return;
            auto it = cells_.find(key);
            if (it == cells_.end()) return;
            for (uint32_t i : it->second)
                if (overlaps(i)) {
                    hit = true;
                    return;
                }
        });
        return hit;
    }
    void insert(const Tri2& tri) {
        const auto id = uint32_t(triangles_.size());
        triangles_.push_back(tri);
        boxes_.push_back(box_of(tri));
        // A long sliver would fill thousands of cells; such triangles are few
        // and are tested against every candidate instead.
        if (cell_span(tri) > 1024) {
            wide_.push_back(id);
            return;
        }
        for_cells(tri, [&](uint64_t key) { cells_[key].push_back(id); });
    }

private:
    struct Box {
        glm::dvec2 lo, hi;
    };
    static Box box_of(const Tri2& t) {
        return {glm::min(glm::min(t[0], t[1]), t[2]), glm::max(glm::max(t[0], t[1]), t[2])};
    }
    static bool boxes_overlap(const Box& a, const Box& b) {
        return a.lo.x < b.hi.x && b.lo.x < a.hi.x && a.lo.y < b.hi.y && b.lo.y < a.hi.y;
    }

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
    std::vector<Box> boxes_;  // of each triangle
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
// A chart is of meshes with a lightmap or of meshes without (lightmap scale
// 0) alone: the latter's charts get one texel.
std::vector<Chart> segment_charts(const Scene& scene, const TriangleAdjacency& adjacency, float max_angle_degrees,
                                  std::vector<uint32_t>& triangle_chart) {
    const size_t n = scene.triangles.size();
    std::vector<float> area(n);
    std::vector<glm::vec3> normal(n);
    const std::vector<uint8_t> without_lightmap = scene.triangles_without_lightmap();
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
            if (without_lightmap[t] != without_lightmap[seed]) return false;
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

// Writes the corner coordinates of the chart's i-th triangle into
// corners[i] (metres, origin at the chart's bounding-rectangle corner, wider
// than tall) and returns its size. The projection is scaled so the chart's
// 2D area equals its world area: the texel density is then exact for every
// chart, flat or gently curved.
ChartShape lay_out_chart(const Scene& scene, const Chart& chart, Tri2* corners) {
    const size_t n = chart.triangles.size();
    double world_area = 0.0, projected_area = 0.0;
    std::vector<glm::dvec2> points;
    points.reserve(n * 3);
    for (size_t i = 0; i < n; ++i) {
        corners[i] = project_triangle(scene, chart.plane, chart.triangles[i]);
        world_area += scene.triangle_area(chart.triangles[i]);
        projected_area += 0.5 * std::abs(signed_area2(corners[i]));
        points.insert(points.end(), corners[i].begin(), corners[i].end());
    }
    const glm::dvec2 d = min_area_rect_direction(convex_hull(points));
    const glm::dvec2 p(-d.y, d.x);
    const double scale = projected_area > 0.0 ? std::sqrt(world_area / projected_area) : 1.0;

    glm::dvec2 lo(1e300), hi(-1e300);
    for (size_t i = 0; i < n; ++i)
        for (glm::dvec2& c : corners[i]) {
            c = scale * glm::dvec2(glm::dot(c, d), glm::dot(c, p));
            lo = glm::min(lo, c);
            hi = glm::max(hi, c);
        }
    // Wide: small charts are packed as laid out or turned by 180° only
    // (kQuarterTurnTexels), and wide ones fill a row's gaps better.
    const bool turn = (hi.y - lo.y) > (hi.x - lo.x);
    for (size_t i = 0; i < n; ++i)
        for (glm::dvec2& c : corners[i]) {
            c -= lo;
            if (turn) c = glm::dvec2(c.y, c.x);
        }
    glm::dvec2 size = hi - lo;
    if (turn) size = glm::dvec2(size.y, size.x);
    return {size};
}

// ---------------------------------------------------------------------------
// Packing by texel shape: every chart is rasterized to the texels its
// triangles touch and placed in a bitmap of the atlas, so small charts fill
// the gaps beside large ones and a triangle's empty half-rectangle is used.

// Charts laid out in their own frames (lay_out_chart): the corners of
// every chart's triangles in metres, chart after chart (so that rasterizing
// a chart reads them in order), and every chart's extent.
struct ChartLayout {
    std::vector<Chart> charts;
    std::vector<Tri2> corners;  // chart c's i-th triangle: corners[first[c] + i]
    std::vector<uint32_t> first;
    std::vector<ChartShape> shapes;
    const Tri2* corners_of(size_t c) const { return corners.data() + first[c]; }
    Tri2* corners_of(size_t c) { return corners.data() + first[c]; }
};

ChartLayout lay_out_charts(const Scene& scene, std::vector<Chart> charts) {
    ChartLayout layout{std::move(charts), std::vector<Tri2>(scene.triangles.size()), {}, {}};
    layout.first.resize(layout.charts.size());
    layout.shapes.resize(layout.charts.size());
    uint32_t next = 0;
    for (size_t c = 0; c < layout.charts.size(); ++c) {
        layout.first[c] = next;
        next += uint32_t(layout.charts[c].triangles.size());
    }
    parallel_for(layout.charts.size(), 64,
                 [&](size_t c) { layout.shapes[c] = lay_out_chart(scene, layout.charts[c], layout.corners_of(c)); });
    return layout;
}

// A chart's rectangle in whole texels: its extent at the density, rounded up
// (at least one texel, so a chart smaller than a texel still owns one).
glm::ivec2 chart_rect(glm::dvec2 size, double density) {
    // Clamped before the conversion: a chart of a hostile scene (coordinates
    // of 1e21 m, found by fuzzing) would overflow int; any side this large
    // fails to pack anyway.
    constexpr double kLargest = 1 << 30;
    auto side = [&](double metres) {
        const double texels = std::ceil(metres * density - 1e-9);
        return std::max(1, int(std::isfinite(texels) ? std::min(texels, kLargest) : kLargest));
    };
    return {side(size.x), side(size.y)};
}

// Where the chart's frame starts in its rectangle (texels): centred. The
// texels are rasterized at this offset, and centring makes a turned chart's
// texels exactly its texels turned.
glm::dvec2 chart_offset(glm::dvec2 size, double density) {
    return glm::max(0.5 * (glm::dvec2(chart_rect(size, density)) - size * density), 0.0);
}

// The turns tried, in this order: 0°, 180°, 90°, 270°.
constexpr int kTurns = 4;

glm::dvec2 turned_size(glm::dvec2 size, int turn) { return turn < 2 ? size : glm::dvec2(size.y, size.x); }

// A corner of a chart of `size` (metres, its frame) after the chart's turn:
// the turned chart again has its bounding-rectangle corner at the origin.
glm::dvec2 turn_corner(glm::dvec2 c, glm::dvec2 size, int turn) {
    switch (turn) {
    case 1: return size - c;
    case 2: return {size.y - c.y, c.x};
    case 3: return {c.y, size.x - c.x};
    default: return c;
    }
}

// One row of a texel mask: its set texels lie in [lo, hi), their bits stored
// from column lo in words [word, word + ceil((hi - lo) / 64)), so a diagonal
// chart costs its texels rather than its rectangle. `run` is the longest run
// of set texels (an atlas row with no free run that long cannot take it).
struct MaskRow {
    int lo = 0, hi = 0, run = 0, texels = 0;
    uint32_t word = 0;
    bool solid() const { return texels == hi - lo; }  // every texel in [lo, hi) set
};

// The packer also looks at 2, 4 and 8 rows at once (levels 1 to 3). A mask
// of h rows is cut into groups of 2^l rows (the largest 2^l <= h, l <= 3;
// the last group overlapping the one before if h is not a multiple), and a
// group's core is the run of columns set in all its rows: the mask fits only
// where as many columns are free in all of them, which one look at the
// level's bitmap tells.
constexpr int kLevels = 4;

struct Core {
    int row = 0, lo = 0, len = 0;  // columns [lo, lo + len) of the group from `row`
};

struct Mask {
    glm::ivec2 size{0};  // its rectangle in whole texels
    uint32_t first_row = 0;
    size_t texels = 0;
    int same_as = -1;                    // an earlier turn of the same chart with the same texels
    uint32_t shape = 0;                  // masks with the same texels share their rows and this number
    int level = 0;                       // its groups' level
    uint32_t first_core = 0, cores = 0;  // the groups with a core (none if no row is solid)
};

struct TexelRun {
    int row, lo, hi;  // texels [lo, hi) of a row
};

// The texel masks of every chart in each of its kTurns turns.
struct TexelMasks {
    std::vector<Mask> masks;  // chart c turned t: masks[c * kTurns + t]
    std::vector<MaskRow> rows;
    std::vector<uint64_t> words;
    std::vector<Core> cores;
    double padded = 0.0;                             // padded_texels of all charts
    bool one_texel_each = true;                      // every chart is one texel (a lower density packs the same)
    uint32_t shapes = 0;                             // distinct masks (Mask::shape)
    std::unordered_map<uint64_t, uint32_t> by_hash;  // a mask of each shape, by texels_hash
    const Mask& mask(size_t chart, int turn) const { return masks[chart * kTurns + size_t(turn)]; }
    const uint64_t* bits(const MaskRow& row) const { return words.data() + row.word; }
    void clear() {  // keeps the memory, for the next packing attempt
        masks.clear();
        rows.clear();
        words.clear();
        cores.clear();
        padded = 0.0;
        one_texel_each = true;
        shapes = 0;
        by_hash.clear();
    }
};

int word_count(int bits) { return (bits + 63) / 64; }

void set_bits(uint64_t* words, int from, int to) {  // bits [from, to)
    while (from < to) {
        const int i = from / 64, shift = from % 64, n = std::min(64 - shift, to - from);
        words[i] |= (n == 64 ? ~uint64_t(0) : (uint64_t(1) << n) - 1) << shift;
        from += n;
    }
}

// The longest run of set bits in `count` words.
int longest_run(const uint64_t* words, size_t count) {
    int best = 0, current = 0;
    for (size_t i = 0; i < count; ++i) {
        const uint64_t v = words[i];
        if (v == ~uint64_t(0)) {
            current += 64;
            continue;
        }
        best = std::max(best, current + std::countr_one(v));
        int inside = 0;  // the longest run within the word: each step shortens every run by one
        for (uint64_t x = v; x != 0; x &= x << 1) ++inside;
        best = std::max(best, inside);
        current = std::countl_one(v);
    }
    return std::max(best, current);
}

// Calls visit(row, lo, hi) for runs of set texels of `m` (a run may come in
// pieces at word boundaries).
template <typename Visit>
void for_each_run(const TexelMasks& set, const Mask& m, Visit&& visit) {
    for (int r = 0; r < m.size.y; ++r) {
        const MaskRow& row = set.rows[m.first_row + uint32_t(r)];
        const uint64_t* bits = set.bits(row);
        for (int k = 0; k < word_count(row.hi - row.lo); ++k)
            for (uint64_t v = bits[k]; v != 0;) {
                const int from = std::countr_zero(v), n = std::countr_one(v >> from);
                visit(r, row.lo + 64 * k + from, row.lo + 64 * k + from + n);
                v = from + n == 64 ? 0 : v & (~uint64_t(0) << (from + n));
            }
    }
}

// The cores of the mask's groups (see Core): its solid rows' spans intersected.
void add_cores(TexelMasks& set, Mask& m) {
    const MaskRow* rows = &set.rows[m.first_row];
    m.level = std::min(kLevels - 1, int(std::bit_width(unsigned(m.size.y))) - 1);
    const int group = 1 << m.level;
    m.first_core = uint32_t(set.cores.size());
    for (int first = 0; first < m.size.y; first += group) {
        const int row = std::min(first, m.size.y - group);
        int lo = 0, hi = INT32_MAX;
        for (int r = row; r < row + group; ++r) {
            lo = std::max(lo, rows[r].solid() ? rows[r].lo : INT32_MAX);
            hi = std::min(hi, rows[r].hi);
        }
        if (hi <= lo) continue;
        set.cores.push_back({row, lo, hi - lo});
        ++m.cores;
    }
}

// Appends the mask of the texels in `runs` (any order, overlaps allowed) to
// `set`; its rectangle is `size`.
void add_mask(TexelMasks& set, glm::ivec2 size, const std::vector<TexelRun>& runs) {
    Mask m;
    m.size = size;
    m.first_row = uint32_t(set.rows.size());
    set.rows.resize(set.rows.size() + size_t(size.y), MaskRow{INT32_MAX, 0});
    MaskRow* rows = &set.rows[m.first_row];
    for (const TexelRun& run : runs) {
        rows[run.row].lo = std::min(rows[run.row].lo, run.lo);
        rows[run.row].hi = std::max(rows[run.row].hi, run.hi);
    }
    for (int r = 0; r < size.y; ++r) {
        MaskRow& row = rows[r];
        if (row.lo > row.hi) row.lo = row.hi = 0;  // no texels
        row.word = uint32_t(set.words.size());
        set.words.resize(set.words.size() + size_t(word_count(row.hi - row.lo)), 0);
    }
    for (const TexelRun& run : runs)
        set_bits(&set.words[rows[run.row].word], run.lo - rows[run.row].lo, run.hi - rows[run.row].lo);
    for (int r = 0; r < size.y; ++r) {
        MaskRow& row = rows[r];
        const size_t n = size_t(word_count(row.hi - row.lo));
        row.texels = 0;
        for (size_t k = 0; k < n; ++k) row.texels += std::popcount(set.words[row.word + k]);
        row.run = longest_run(&set.words[row.word], n);
        m.texels += size_t(row.texels);
    }
    add_cores(set, m);
    set.masks.push_back(m);
}

bool same_texels(const TexelMasks& set, const Mask& a, const Mask& b) {
    if (a.size != b.size) return false;
    for (uint32_t r = 0; r < uint32_t(a.size.y); ++r) {
        const MaskRow &x = set.rows[a.first_row + r], &y = set.rows[b.first_row + r];
        if (x.lo != y.lo || x.hi != y.hi ||
            !std::equal(set.bits(x), set.bits(x) + word_count(x.hi - x.lo), set.bits(y)))
            return false;
    }
    return true;
}

// How close a triangle must come to a texel for the texel to be in its
// chart's mask. coverage_mask and the texel samples give a triangle the
// texels it reaches kTouchDepth (1e-3 texel) into, or the one holding its
// centroid; float UVs move a corner by at most 2.4e-4 texel at 8192².
constexpr double kSlack = 1e-3;

// The texel that holds coordinate v, floor(v), clamped to [0, last]; and
// the last texel an extent ending at v reaches, ceil(v) - 1, clamped so.
// (Conversions, not std::floor and std::ceil: those are calls without
// SSE4.1, and these run for every row of every triangle. NaN goes to 0.)
int first_texel(double v, int last) { return !(v > 0.0) ? 0 : v >= last ? last : int(v); }
int last_texel(double v, int last) {
    if (!(v > 0.0)) return 0;
    if (v > last + 1) return last;
    const int t = int(v);
    return std::min(last, t == v ? t - 1 : t);
}

// Appends the texels within kSlack of triangle `p` (texels, in its chart's
// rectangle `rect`), one run per row. With the corners sorted by y, the
// triangle's x extent over a row's strip is reached at the strip's ends on
// the long edge and on the two short ones, or at the middle corner.
void triangle_runs(Tri2 p, glm::ivec2 rect, std::vector<TexelRun>& runs) {
    if (p[1].y < p[0].y) std::swap(p[0], p[1]);
    if (p[2].y < p[1].y) std::swap(p[1], p[2]);
    if (p[1].y < p[0].y) std::swap(p[0], p[1]);
    const int y0 = first_texel(p[0].y - kSlack, rect.y - 1), y1 = last_texel(p[2].y + kSlack, rect.y - 1);
    auto add = [&](int y, double lo, double hi) {
        runs.push_back({y, first_texel(lo - kSlack, rect.x - 1), last_texel(hi + kSlack, rect.x - 1) + 1});
    };
    if (y0 == y1 || !(p[2].y > p[0].y)) {  // within one row's strip, or flat: its whole extent
        for (int y = y0; y <= y1; ++y) add(y, std::min({p[0].x, p[1].x, p[2].x}), std::max({p[0].x, p[1].x, p[2].x}));
        return;
    }
    auto slope = [](glm::dvec2 a, glm::dvec2 b) { return b.y > a.y ? (b.x - a.x) / (b.y - a.y) : 0.0; };
    const double long_slope = slope(p[0], p[2]), upper = slope(p[0], p[1]), lower = slope(p[1], p[2]);
    auto long_x = [&](double y) { return p[0].x + (y - p[0].y) * long_slope; };
    auto short_x = [&](double y) { return y < p[1].y ? p[0].x + (y - p[0].y) * upper : p[1].x + (y - p[1].y) * lower; };
    for (int y = y0; y <= y1; ++y) {
        const double a = std::max(y - kSlack, p[0].y), b = std::min(y + 1 + kSlack, p[2].y);
        if (!(a <= b)) continue;
        double lo = std::min({long_x(a), long_x(b), short_x(a), short_x(b)});
        double hi = std::max({long_x(a), long_x(b), short_x(a), short_x(b)});
        if (a <= p[1].y && p[1].y <= b) {
            lo = std::min(lo, p[1].x);
            hi = std::max(hi, p[1].x);
        }
        add(y, lo, hi);
    }
}

// Appends chart c's texels at `density` turned by `turn` to `runs`: its
// corners turned and placed in its turned rectangle as chart_corner_uvs
// places them.
void chart_runs(const ChartLayout& layout, size_t c, double density, int turn, std::vector<TexelRun>& runs) {
    const glm::dvec2 size = layout.shapes[c].size, turned = turned_size(size, turn);
    const glm::ivec2 rect = chart_rect(turned, density);
    if (rect == glm::ivec2(1)) {  // the whole chart lies in its one texel
        runs.push_back({0, 0, 1});
        return;
    }
    const glm::dvec2 offset = chart_offset(turned, density);
    auto place = [&](glm::dvec2 corner) { return offset + turn_corner(corner, size, turn) * density; };
    const Tri2* corners = layout.corners_of(c);
    for (size_t i = 0; i < layout.charts[c].triangles.size(); ++i)
        triangle_runs({place(corners[i][0]), place(corners[i][1]), place(corners[i][2])}, rect, runs);
    if (runs.empty()) runs.push_back({0, 0, 1});  // (non-finite corners) every chart owns a texel
}

// A hash of the mask's texels.
uint64_t texels_hash(const TexelMasks& set, const Mask& m) {
    uint64_t h = 0x9e3779b97f4a7c15ull ^ (uint64_t(uint32_t(m.size.x)) << 32 | uint32_t(m.size.y));
    auto mix = [&](uint64_t v) {
        h = (h ^ v) * 0xff51afd7ed558ccdull;
        h ^= h >> 32;
    };
    for (uint32_t r = 0; r < uint32_t(m.size.y); ++r) {
        const MaskRow& row = set.rows[m.first_row + r];
        mix(uint64_t(uint32_t(row.lo)) << 32 | uint32_t(row.hi));
        for (int k = 0; k < word_count(row.hi - row.lo); ++k) mix(set.bits(row)[k]);
    }
    return h;
}

// Keeps the mask just added once per shape: if an earlier one has the same
// texels, the new one becomes a copy of it (charts of a repeated mesh come
// out the same), else it gets a new shape number. A turn with the texels of
// an earlier turn of the same chart is marked, so that it is not tried twice.
void share_shape(TexelMasks& set, size_t first_turn, size_t rows, size_t words, size_t cores) {
    Mask& m = set.masks.back();
    const auto [it, added] = set.by_hash.try_emplace(texels_hash(set, m), uint32_t(set.masks.size() - 1));
    if (added || !same_texels(set, m, set.masks[it->second])) {
        m.shape = set.shapes++;
    } else {
        set.rows.resize(rows);
        set.words.resize(words);
        set.cores.resize(cores);
        m = set.masks[it->second];
        m.same_as = -1;
    }
    for (size_t turn = first_turn; turn + 1 < set.masks.size(); ++turn)
        if (set.masks[turn].shape == m.shape) {
            m.same_as = int(turn - first_turn);
            break;
        }
}

// Charts of fewer texels are not tried turned by 90° and 270°: their masks
// are nearly their rectangles, laid out wide, and trying those turns for
// them too moved no shared scene's density by more than 1.3% (monkey.glb's
// auto atlas) while taking a third of the packing's time. For larger charts
// they are worth it: 2% more texels/m for the staircase at 1024².
constexpr size_t kQuarterTurnTexels = 64;

// A chart's texel runs as rasterized (chart_runs): turned by 0° and, where
// add_chart_masks may need them, by 90°.
struct RasterizedChart {
    std::array<std::vector<TexelRun>, 2> turns;  // 0° (turn 0), 90° (turn 2)
};

// Rasterizes chart c for add_chart_masks: the 90° turn only where the
// chart's rectangle holds kQuarterTurnTexels or more (its mask, no larger,
// may then have that many texels).
void rasterize_chart(const ChartLayout& layout, size_t c, double density, RasterizedChart& out) {
    for (std::vector<TexelRun>& runs : out.turns) runs.clear();
    chart_runs(layout, c, density, 0, out.turns[0]);
    const glm::ivec2 rect = chart_rect(layout.shapes[c].size, density);
    if (size_t(rect.x) * size_t(rect.y) >= kQuarterTurnTexels) chart_runs(layout, c, density, 2, out.turns[1]);
}

// Appends chart c's masks in each of its kTurns turns. The 0° and 90° turns
// are rasterized (`chart`, whose runs are used up); the 180° and 270° ones
// are those turned by 180° (texel (i, j) of a w x h mask to
// (w-1-i, h-1-j)), which is exact because a chart is centred in its
// rectangle.
void add_chart_masks(TexelMasks& set, const ChartLayout& layout, size_t c, double density, RasterizedChart& chart) {
    const size_t first = set.masks.size();
    for (int turn = 0; turn < kTurns; ++turn) {
        if (turn == 2 && set.masks[first].texels < kQuarterTurnTexels) {
            for (; turn < kTurns; ++turn) {
                set.masks.push_back(set.masks[first]);
                set.masks.back().same_as = 0;  // not tried
            }
            return;
        }
        const glm::ivec2 rect = chart_rect(turned_size(layout.shapes[c].size, turn), density);
        std::vector<TexelRun>& runs = chart.turns[size_t(turn / 2)];
        if (turn % 2 == 1)
            for (TexelRun& run : runs) run = {rect.y - 1 - run.row, rect.x - run.hi, rect.x - run.lo};
        const size_t rows = set.rows.size(), words = set.words.size(), cores = set.cores.size();
        add_mask(set, rect, runs);
        share_shape(set, first, rows, words, cores);
    }
}

// A lower bound on the texels of mask `m` dilated by r (Chebyshev): each
// row's texels grow by at least 2r, and the r rows above and below it hold at
// least its first and last rows' texels grown so. Charts `padding` apart
// keep their masks dilated by padding / 2 apart, so these add up to at most
// (side + padding)² texels of the atlas (the dilation may hang over its edge).
double padded_texels(const TexelMasks& set, const Mask& m, int r) {
    const MaskRow* rows = &set.rows[m.first_row];
    double sum = r * (rows[0].texels + rows[m.size.y - 1].texels + 4.0 * r);
    for (int y = 0; y < m.size.y; ++y) sum += rows[y].texels + 2.0 * r;
    return sum;
}

// The texel masks of every chart at `density`, in every turn, into `set`;
// false when they cannot fit a size x size atlas (or `pages` of them): a rectangle wider than it,
// too many texels (padded_texels), or (a hostile scene's hollow charts)
// masks of more than 32 bits per atlas texel.
//
// The charts are rasterized on every core, a block at a time, and their
// masks added in chart order (the same set on any number of threads); an
// attempt that cannot fit stops at the block where it fails.
bool chart_masks(const ChartLayout& layout, double density, int size, int padding, TexelMasks& set, int pages = 1) {
    const double atlas = double(size) * double(size) * pages,
                 padded_atlas = double(size + padding) * double(size + padding) * pages;
    set.clear();
    constexpr size_t kBlock = 2048;
    std::vector<RasterizedChart> block(std::min(kBlock, layout.charts.size()));
    for (size_t begin = 0; begin < layout.charts.size(); begin += kBlock) {
        const size_t end = std::min(layout.charts.size(), begin + kBlock);
        for (size_t c = begin; c < end; ++c) {
            const glm::ivec2 rect = chart_rect(layout.shapes[c].size, density);
            if (rect.x > size || rect.y > size) return false;
        }
        parallel_for(end - begin, 16, [&](size_t k) { rasterize_chart(layout, begin + k, density, block[k]); });
        for (size_t c = begin; c < end; ++c) {
            add_chart_masks(set, layout, c, density, block[c - begin]);
            set.padded += padded_texels(set, set.mask(c, 0), padding / 2);
            set.one_texel_each = set.one_texel_each && chart_rect(layout.shapes[c].size, density) == glm::ivec2(1);
            if (set.padded > padded_atlas || double(set.words.size()) > atlas / 2.0 + 65536.0) return false;
        }
    }
    return true;
}

// A size x size bitmap of the texels taken: every placed chart's texels
// dilated by `padding` (Chebyshev), so a chart whose texels miss them all
// keeps `padding` empty texels to every other chart. The dilation may hang
// over the atlas's edge, as charts may touch it.
class ShapePacker {
public:
    // An empty size x size atlas (the memory of the last one kept).
    void reset(int size, int padding) {
        size_ = size;
        padding_ = padding;
        stride_ = size_t(word_count(size)) + 2;
        leaves_ = std::bit_ceil(size_t(size));
        for (int level = 0; level < kLevels; ++level) {
            // Columns from `size` on are taken (no mask reaches past the
            // edge; 128 columns read from any column stay in the row), and
            // so are level rows that would reach past the bottom. The rest
            // are like the first row.
            const int rows = std::max(0, size - (1 << level) + 1);
            taken_[size_t(level)].assign(size_t(size) * stride_, ~uint64_t(0));
            starts_[size_t(level)].assign(size_t(size) * stride_, 0);
            longest_[size_t(level)].assign(2 * leaves_, 0);
            if (rows == 0) continue;
            std::fill_n(row(level, 0), stride_, 0);
            set_bits(row(level, 0), size, int(stride_) * 64);
            update_runs(level, 0, 1, 0, size);
            for (int y = 1; y < rows; ++y) {
                std::copy_n(row(level, 0), stride_, row(level, y));
                std::copy_n(&starts_[size_t(level)][0], stride_, &starts_[size_t(level)][size_t(y) * stride_]);
                longest_[size_t(level)][leaves_ + size_t(y)] = size;
            }
            for (size_t i = leaves_ - 1; i > 0; --i)
                longest_[size_t(level)][i] =
                    std::max(longest_[size_t(level)][2 * i], longest_[size_t(level)][2 * i + 1]);
        }
    }

    // The top-left corner of the lowest (then leftmost) place where `m`
    // fits, its top row from from_y to max_y; from_y is left at that row
    // (or past max_y), no row before it having a place. Rows where a core or
    // a row of the mask has no free run as long as its own are skipped
    // (possible_row); in the others, 64 places are tested at a time: by
    // may_fit's blocks, then exactly, its cores first.
    std::optional<glm::ivec2> find(const TexelMasks& set, const Mask& m, int& from_y, int max_y) const {
        const Core* cores = set.cores.data() + m.first_core;
        const int last_x = size_ - m.size.x, last_y = std::min(max_y, size_ - m.size.y);
        for (int& y = from_y; (y = possible_row(set, m, y)) <= last_y; ++y)
            for (int x = 0; x <= last_x; x += 64) {
                if (!may_fit(set, m, {x, y})) continue;
                uint64_t fits = last_x - x >= 63 ? ~uint64_t(0) : (uint64_t(1) << (last_x - x + 1)) - 1;
                for (uint32_t c = 0; c < m.cores && fits != 0; ++c)
                    fits &= free_runs(m.level, y + cores[c].row, x + cores[c].lo, std::min(cores[c].len, 64));
                for (int r = 0; r < m.size.y && fits != 0; ++r)
                    fits &= row_fits(set, set.rows[m.first_row + uint32_t(r)], y + r, x);
                if (fits != 0) return glm::ivec2(x + std::countr_zero(fits), y);
            }
        return std::nullopt;
    }

    // Marks the mask's texels, dilated by the padding, taken at every level.
    void take(const TexelMasks& set, const Mask& m, glm::ivec2 at) {
        const int p = padding_;
        for_each_run(set, m, [&](int r, int lo, int hi) {
            const int from = std::max(0, at.x + lo - p), to = std::min(size_, at.x + hi + p);
            for (int y = std::max(0, at.y + r - p); y <= std::min(size_ - 1, at.y + r + p); ++y)
                set_bits(row(0, y), from, to);
        });
        const int top = std::max(0, at.y - p), bottom = std::min(size_, at.y + m.size.y + p);
        const int first_word = std::max(0, at.x - p) / 64, last_word = std::min(size_ - 1, at.x + m.size.x + p) / 64;
        update_runs(0, top, bottom, first_word * 64, std::min(size_, (last_word + 1) * 64));
        for (int level = 1; level < kLevels; ++level) {
            const int half = 1 << (level - 1), from = std::max(0, top - (1 << level) + 1);
            const int to = std::min(bottom, size_ - (1 << level) + 1);  // rows past the bottom stay taken
            for (int y = from; y < to; ++y)
                for (int k = first_word; k <= last_word; ++k)
                    row(level, y)[k] = row(level - 1, y)[k] | row(level - 1, y + half)[k];
            update_runs(level, from, to, first_word * 64, std::min(size_, (last_word + 1) * 64));
        }
    }

private:
    using Bits128 = unsigned __int128;

    uint64_t* row(int level, int y) { return &taken_[size_t(level)][size_t(y) * stride_]; }
    const uint64_t* row(int level, int y) const { return &taken_[size_t(level)][size_t(y) * stride_]; }

    // Measures the free runs of `level`'s rows [from, to), where columns
    // [left, right) changed: for each block of 64 columns, the longest free
    // run starting in it (blocks from the start of the run that reached
    // `left`); for each row (the tree's leaf), the longest of all.
    void update_runs(int level, int from, int to, int left, int right) {
        std::vector<int>& longest = longest_[size_t(level)];
        for (int y = from; y < to; ++y) {
            const uint64_t* bits = row(level, y);
            uint16_t* starts = &starts_[size_t(level)][size_t(y) * stride_];
            const int first = (left > 0 ? previous_taken(bits, left - 1) + 1 : 0) / 64, last = (right - 1) / 64;
            std::fill(starts + first, starts + last + 1, uint16_t(0));
            for (int x = next_bit(bits, first * 64, false); x < (last + 1) * 64 && x < size_;) {
                const int end = next_bit(bits, x, true);  // a taken column always follows (the edge)
                for (int block = x / 64; block <= last && block * 64 < end; ++block)
                    starts[block] =
                        uint16_t(std::max<int>(starts[block], std::min(end - std::max(x, block * 64), 65535)));
                x = next_bit(bits, end, false);
            }
            size_t i = leaves_ + size_t(y);
            longest[i] = *std::max_element(starts, starts + stride_);
            for (i /= 2; i > 0; i /= 2) longest[i] = std::max(longest[2 * i], longest[2 * i + 1]);
        }
    }

    // The last taken column up to x (-1 if none).
    static int previous_taken(const uint64_t* bits, int x) {
        size_t i = size_t(x / 64);
        uint64_t v = bits[i] & (~uint64_t(0) >> (63 - x % 64));
        while (v == 0 && i > 0) v = bits[--i];
        return v == 0 ? -1 : int(i) * 64 + 63 - std::countl_zero(v);
    }

    // The first column from x on whose bit is `taken` (size when none is free).
    int next_bit(const uint64_t* bits, int x, bool taken) const {
        if (x >= size_) return taken ? x : size_;
        size_t i = size_t(x / 64);
        uint64_t v = (taken ? bits[i] : ~bits[i]) & (~uint64_t(0) << (x % 64));
        while (v == 0 && ++i < stride_) v = taken ? bits[i] : ~bits[i];
        return v == 0 ? size_ : int(i) * 64 + std::countr_zero(v);
    }

    // The first row from `from` on whose longest free run at `level` is at
    // least `len` (size when none): the next few rows are looked at in
    // turn, then the tree is walked up to the first subtree on the right
    // that has one, and down it.
    int next_row(int level, int from, int len) const {
        const int* leaf = &longest_[size_t(level)][leaves_];
        for (int y = from; y < std::min(from + 8, size_); ++y)
            if (leaf[y] >= len) return y;
        if (from + 8 >= size_) return size_;
        const std::vector<int>& longest = longest_[size_t(level)];
        size_t i = leaves_ + size_t(from + 7);
        while (i > 1 && !((i & 1) == 0 && longest[i + 1] >= len)) i /= 2;
        if (i == 1) return size_;
        for (++i; i < leaves_;) i = longest[2 * i] >= len ? 2 * i : 2 * i + 1;
        return int(i - leaves_);
    }

    // Whether a free run of `len` columns starts within [x, x + 64) of
    // `level`'s row y, by the longest runs starting in its blocks.
    bool run_starts(int level, int y, int x, int len) const {
        const uint16_t* starts = &starts_[size_t(level)][size_t(y) * stride_ + size_t(x / 64)];
        return starts[0] >= len || (x % 64 != 0 && starts[1] >= len);
    }

    // False when no place in [at.x, at.x + 64) can fit `m` (its top row at
    // at.y): a core or a solid row finds no free run of its length starting
    // where it would.
    bool may_fit(const TexelMasks& set, const Mask& m, glm::ivec2 at) const {
        for (uint32_t c = m.first_core; c < m.first_core + m.cores; ++c) {
            const Core& core = set.cores[c];
            if (!run_starts(m.level, at.y + core.row, at.x + core.lo, core.len)) return false;
        }
        for (int r = 0; r < m.size.y; ++r) {
            const MaskRow& row = set.rows[m.first_row + uint32_t(r)];
            if (row.solid() && !run_starts(0, at.y + r, at.x + row.lo, row.hi - row.lo)) return false;
        }
        return true;
    }

    // The first row from y on where every core and every row of `m` has a
    // free run as long as its own in its rows (past the last row if none):
    // each that has none moves y on to the next row where it has, until
    // none moves it.
    int possible_row(const TexelMasks& set, const Mask& m, int y) const {
        for (bool moved = true; moved && y <= size_ - m.size.y;) {
            moved = false;
            auto skip = [&](int level, int row, int len) {  // len > 0
                const int next = next_row(level, y + row, len) - row;
                moved = moved || next > y;
                y = std::max(y, next);
            };
            for (uint32_t c = m.first_core; c < m.first_core + m.cores; ++c)
                skip(m.level, set.cores[c].row, set.cores[c].len);
            for (int r = 0; r < m.size.y && y <= size_ - m.size.y; ++r)
                if (const int run = set.rows[m.first_row + uint32_t(r)].run; run > 0) skip(0, r, run);
        }
        return y;
    }

    // Bit i set where [x + i, x + i + len) is free in `level`'s row y (x < size, len <= 64).
    uint64_t free_runs(int level, int y, int x, int len) const {
        const uint64_t* w = row(level, y) + x / 64;
        const int shift = x % 64;
        Bits128 taken = (Bits128(w[1]) << 64 | w[0]) >> shift;
        if (shift != 0) taken |= Bits128(w[2]) << (128 - shift);
        Bits128 runs = ~taken;
        for (int covered = 1; covered < len && runs != 0;) {  // runs of `covered` free columns, doubling
            const int step = std::min(covered, len - covered);
            runs &= runs >> step;
            covered += step;
        }
        return uint64_t(runs);
    }

    // Bit i set where mask row `mask_row` misses the taken texels of row y
    // with its left column at x + i.
    uint64_t row_fits(const TexelMasks& set, const MaskRow& mask_row, int y, int x) const {
        if (mask_row.solid() && mask_row.hi - mask_row.lo <= 64) return free_runs(0, y, x + mask_row.lo, mask_row.run);
        uint64_t fits = ~uint64_t(0);
        const uint64_t* texels = set.bits(mask_row);
        for (int k = 0; k < word_count(mask_row.hi - mask_row.lo) && fits != 0; ++k)
            for (uint64_t v = texels[k]; v != 0 && fits != 0;) {
                const int from = std::countr_zero(v), n = std::countr_one(v >> from);
                fits &= free_runs(0, y, x + mask_row.lo + 64 * k + from, n);
                v = from + n == 64 ? 0 : v & (~uint64_t(0) << (from + n));
            }
        return fits;
    }

    int size_ = 0, padding_ = 0;
    size_t stride_ = 0;  // words per row
    size_t leaves_ = 0;
    // Per level: size rows of stride_ words, a column taken in any of the
    // level's rows; and a binary tree over the rows (leaves from leaves_ on)
    // of their longest free runs, each node the most of those below it.
    std::array<std::vector<uint64_t>, kLevels> taken_;
    std::array<std::vector<uint16_t>, kLevels> starts_;  // per row, per block of 64 columns: update_runs
    std::array<std::vector<int>, kLevels> longest_;
};

struct Placement {
    glm::ivec2 at{0};  // top-left texel of the chart's (turned) rectangle on its page
    int turn = 0;      // turn_corner's
    int page = 0;
};

// One packing attempt, and what it says about the density to try next.
struct PackAttempt {
    std::optional<std::vector<Placement>> at;  // when every chart fits
    int rows = 0;                              // fits, one page: rows down to the lowest chart's bottom
    bool one_texel_each = false;               // misses: as small as the charts get
    int pages = 1;                             // fits: the pages used
    double placed_padded = 0.0;                // misses (pages): padded texels of the charts placed
};

// Charts tallest first as laid out (then with most texels first; the
// staircase at 1024² took 31.5 texels/m so, 29.5 with most texels first).
std::vector<uint32_t> packing_order(const TexelMasks& set) {
    std::vector<uint32_t> order(set.masks.size() / kTurns);
    std::iota(order.begin(), order.end(), 0u);
    std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) {
        const Mask &x = set.mask(a, 0), &y = set.mask(b, 0);
        return x.size.y != y.size.y ? x.size.y > y.size.y : x.texels != y.texels ? x.texels > y.texels : a < b;
    });
    return order;
}

// Chart c at the lowest (then leftmost) place it fits in `packer`'s atlas,
// in whichever of its turns ends lowest (its bottom row, then its left
// column). open_row: per shape, the first row where it may still fit
// (texels are only ever taken, so where one chart did not fit, no chart of
// the same shape will).
std::optional<Placement> best_place(const TexelMasks& set, uint32_t c, int size, const ShapePacker& packer,
                                    std::vector<int>& open_row) {
    std::optional<Placement> best;
    int best_bottom = INT32_MAX;
    for (int turn = 0; turn < kTurns; ++turn) {
        const Mask& m = set.mask(c, turn);
        if (m.same_as >= 0 || m.size.x > size || m.size.y > size) continue;
        // Only a place ending no lower than the best so far is looked for,
        // so one that ends as low wins by its column.
        const auto at = packer.find(set, m, open_row[m.shape], best ? best_bottom - m.size.y : size);
        if (at && (!best || at->y + m.size.y < best_bottom || at->x < best->at.x)) {
            best = Placement{*at, turn};
            best_bottom = at->y + m.size.y;
        }
    }
    return best;
}

PackAttempt pack_charts(const TexelMasks& set, int size, int padding, ShapePacker& packer) {
    packer.reset(size, padding);
    PackAttempt attempt;
    std::vector<Placement> placed(set.masks.size() / kTurns);
    std::vector<int> open_row(set.shapes, 0);
    for (uint32_t c : packing_order(set)) {
        const std::optional<Placement> best = best_place(set, c, size, packer, open_row);
        if (!best) {
            attempt.one_texel_each = set.one_texel_each;
            return attempt;
        }
        packer.take(set, set.mask(c, best->turn), best->at);
        placed[c] = *best;
        attempt.rows = std::max(attempt.rows, best->at.y + set.mask(c, best->turn).size.y);
    }
    attempt.at = std::move(placed);
    return attempt;
}

// The charts on pages of size x size, in packing_order, each on the first
// open page where it fits, a new page opened where none holds it. Only the
// last kOpenPages pages stay open (each packer is ~40 MB at 8192²): an
// older one is as good as full, its gaps too small for what still comes.
// Misses when more than max_pages would be needed.
PackAttempt pack_charts_on_pages(const TexelMasks& set, int size, int padding, int max_pages) {
    constexpr size_t kOpenPages = 4;
    struct OpenPage {
        int number = 0;
        ShapePacker packer;
        std::vector<int> open_row;
    };
    std::vector<std::unique_ptr<OpenPage>> open;
    PackAttempt attempt;
    attempt.pages = 0;
    std::vector<Placement> placed(set.masks.size() / kTurns);
    for (uint32_t c : packing_order(set)) {
        std::optional<Placement> best;
        for (size_t k = 0; k < open.size() && !best; ++k)
            if ((best = best_place(set, c, size, open[k]->packer, open[k]->open_row))) best->page = open[k]->number;
        if (!best) {
            if (attempt.pages == max_pages) {
                attempt.one_texel_each = set.one_texel_each;
                return attempt;
            }
            if (open.size() == kOpenPages) open.erase(open.begin());
            open.push_back(std::make_unique<OpenPage>());
            OpenPage& page = *open.back();
            page.number = attempt.pages++;
            page.packer.reset(size, padding);
            page.open_row.assign(set.shapes, 0);
            best = best_place(set, c, size, page.packer, page.open_row);
            if (!best) return attempt;  // wider or taller than a page
            best->page = page.number;
        }
        for (const auto& page : open)
            if (page->number == best->page) page->packer.take(set, set.mask(c, best->turn), best->at);
        placed[c] = *best;
        attempt.placed_padded += padded_texels(set, set.mask(c, 0), padding / 2);
    }
    attempt.at = std::move(placed);
    return attempt;
}

// What the packing attempts of one search reuse: their memory.
struct PackScratch {
    TexelMasks masks;
    ShapePacker packer;
};

PackAttempt pack_at_density(const ChartLayout& layout, double density, int size, int padding, PackScratch& scratch) {
    if (!chart_masks(layout, density, size, padding, scratch.masks)) return {};
    return pack_charts(scratch.masks, size, padding, scratch.packer);
}

// Texels the charts' rectangles would take, padding included (for first guesses).
double packed_area(const ChartLayout& layout, double density, int padding) {
    double sum = 0.0;
    for (const ChartShape& s : layout.shapes) {
        const glm::ivec2 r = chart_rect(s.size, density);
        sum += double(r.x + padding) * double(r.y + padding);
    }
    return sum;
}

// The density at which the charts' rectangles take about `fill` of the atlas.
double estimate_density(const ChartLayout& layout, double atlas_texels, int padding, double fill) {
    double lo = 0.0, hi = 1.0;
    while (packed_area(layout, hi, padding) < fill * atlas_texels && hi < 1e12) hi *= 2.0;
    for (int i = 0; i < 40; ++i) {
        const double mid = 0.5 * (lo + hi);
        (packed_area(layout, mid, padding) < fill * atlas_texels ? lo : hi) = mid;
    }
    return lo;
}

struct Packing {
    int size = 0;  // square atlas side (with pages: a page's)
    double density = 0.0;
    std::vector<Placement> at;
    int pages = 1;
    int gap = 0;  // empty rows between pages (LightmapPages::gap)
    LightmapPages layout() const { return {pages, size, pages > 1 ? gap : 0}; }
};

// A packing that fitted: its density and the rows down to its lowest chart's bottom.
struct Fit {
    double density = 0.0;
    int rows = 0;
};

// The density to try next, lo being the largest that fitted (`fit`, after
// `earlier`) and hi the smallest that did not (0 and infinity while
// unknown). The rows a packing reaches grow as a power of the density
// (about 2 for large charts, nearer 1 where padding dominates), measured
// between the last two fits: the density at which they would reach `size`
// (0.5% less) is tried while it lies inside the bracket, else its middle.
double next_density(const Fit& fit, const Fit& earlier, int size, double lo, double hi) {
    if (lo == 0.0) return hi * 0.5;  // nothing fitted yet
    double power = 2.0;
    if (earlier.rows > 0 && earlier.rows != fit.rows && earlier.density != fit.density)
        power =
            std::clamp(std::log(double(fit.rows) / earlier.rows) / std::log(fit.density / earlier.density), 0.5, 3.0);
    const double predicted = fit.density * std::pow(double(size) / std::max(fit.rows, 1), 1.0 / power) * 0.995;
    if (!std::isfinite(hi)) return std::max(predicted, lo * 1.01);
    return predicted > lo * 1.005 && predicted < hi / 1.005 ? predicted : 0.5 * (lo + hi);
}

// The largest density (to 1%; at most `density_cap`, if set) whose charts
// fit a size x size atlas, found by packing attempts (next_density), down to
// one texel per chart, which smallest_atlas_resolution packs.
std::optional<Packing> pack_at_resolution(const ChartLayout& layout, int size, int padding, double density_cap) {
    // Never 0: at 0 every chart would collapse to a point.
    double density = std::max(estimate_density(layout, double(size) * size, padding, 0.9), 1e-12);
    if (density_cap > 0.0) density = std::min(density, density_cap);
    std::optional<Packing> best;
    PackScratch scratch;
    Fit fit, earlier;
    double lo = 0.0, hi = INFINITY;
    for (int tries = 0; tries < 100 && !(hi <= lo * 1.01); ++tries) {
        PackAttempt attempt = pack_at_density(layout, density, size, padding, scratch);
        if (attempt.at) {
            best = Packing{size, density, std::move(*attempt.at)};
            lo = density;
            earlier = fit;
            fit = {density, attempt.rows};
            if (density_cap > 0.0 && density >= density_cap) break;
        } else {
            hi = density;
            if (attempt.one_texel_each || density <= 1e-12) break;  // no smaller charts to try
        }
        density = std::max(next_density(fit, earlier, size, lo, hi), 1e-12);
        if (density_cap > 0.0) density = std::min(density, density_cap);
    }
    return best;
}

// The smallest square that holds the charts at `density`, exactly or (not
// `exact`) to 1%, if one up to max_resolution does: from padded_texels'
// lower bound, grown by 3% until the charts fit, then bisected between the
// last miss and the fit.
std::optional<Packing> smallest_square(const ChartLayout& layout, double density, int padding, int max_resolution,
                                       bool exact) {
    PackScratch scratch;
    const TexelMasks& masks = scratch.masks;
    if (!chart_masks(layout, density, max_resolution, padding, scratch.masks)) return std::nullopt;
    int miss = std::clamp(int(std::ceil(std::sqrt(masks.padded))) - padding - 1, 0, max_resolution - 1);
    int size = miss + 1;
    std::optional<std::vector<Placement>> fit;
    while (!(fit = pack_charts(masks, size, padding, scratch.packer).at)) {
        if (size >= max_resolution) return std::nullopt;
        miss = size;
        size = std::min(max_resolution, int(std::ceil(size * 1.03)) + 1);
    }
    while (size - miss > (exact ? 1 : std::max(1, size / 100))) {
        const int mid = miss + (size - miss) / 2;
        if (auto at = pack_charts(masks, mid, padding, scratch.packer).at) {
            fit = std::move(at);
            size = mid;
        } else miss = mid;
    }
    return Packing{size, density, std::move(*fit)};
}

// The charts at `density`, or the largest density below it (to 1%) at
// which they fit, on at most max_pages pages of size x size, `padding` rows
// apart. While nothing fits, the density shrinks by the root of the share
// of the charts that found a place; then it is bisected between the last
// fit and the last miss. None when even one texel each does not fit.
std::optional<Packing> pack_on_pages(const ChartLayout& layout, double density, int size, int padding, int max_pages) {
    // No page holds a chart wider or taller than its side (in either turn):
    // the largest chart spans one page at most.
    double largest = 0.0;
    for (const ChartShape& shape : layout.shapes) largest = std::max({largest, shape.size.x, shape.size.y});
    if (largest > 0.0) density = std::min(density, double(size) / largest * (1.0 - 1e-6));
    std::optional<Packing> best;
    PackScratch scratch;
    double lo = 0.0, hi = density * 1.0000001;  // lo fitted, hi did not (the asked density bounds it)
    for (int tries = 0; tries < 60 && density > 1e-12 && hi > lo * 1.01; ++tries) {
        double placed = 0.0;  // the share of the charts' texels that found a place
        if (chart_masks(layout, density, size, padding, scratch.masks, max_pages)) {
            PackAttempt attempt = pack_charts_on_pages(scratch.masks, size, padding, max_pages);
            if (attempt.at) {
                best = Packing{size, density, std::move(*attempt.at), attempt.pages, padding};
                lo = density;
            } else if (attempt.one_texel_each) {
                break;
            } else {
                placed = attempt.placed_padded / scratch.masks.padded;
            }
        }
        if (lo < density) hi = density;
        density = best ? std::sqrt(lo * hi) : density * std::clamp(0.98 * std::sqrt(placed), 0.5, 0.98);
    }
    return best;
}

Packing pack_atlas(const ChartLayout& layout, const AtlasOptions& options) {
    const int padding = std::max(0, options.padding), max_pages = std::max(1, options.max_pages);
    auto too_small = [&](int size) {
        return AtlasDoesNotFit("atlas: " + std::to_string(layout.charts.size()) + " charts do not fit " +
                               (max_pages > 1 ? std::to_string(max_pages) + " pages of " : std::string("a ")) +
                               std::to_string(size) + "x" + std::to_string(size) +
                               " even at one texel each; raise the resolution" +
                               (max_pages > 1 ? " or max_pages" : ""));
    };
    const double asked = options.texel_density;
    if (options.resolution > 0 || asked <= 0.0) {
        const int size = options.resolution > 0 ? options.resolution : kDefaultResolution;
        std::optional<Packing> packing = pack_at_resolution(layout, size, padding, asked);
        // Pages of this side where one holds less than the asked density, or nothing.
        if (max_pages > 1 && (!packing || (asked > 0.0 && packing->density < 0.99 * asked))) {
            const double density =
                asked > 0.0 ? asked : estimate_density(layout, double(size) * size * max_pages, padding, 0.8);
            std::optional<Packing> paged = pack_on_pages(layout, density, size, padding, max_pages);
            if (paged && (!packing || paged->density > packing->density)) return *paged;
        }
        if (!packing) throw too_small(size);
        return *packing;
    }
    // Density given: the smallest square that holds the charts, up to the
    // cap; else pages of the cap's side; else the density shrinks.
    if (auto packing = smallest_square(layout, asked, padding, options.max_resolution, false)) return *packing;
    if (max_pages > 1)
        if (auto paged = pack_on_pages(layout, asked, options.max_resolution, padding, max_pages)) return *paged;
    auto packing = pack_at_resolution(layout, options.max_resolution, padding, asked);
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
    chosen.max_pages = 1;  // a density chosen for its border fraction shrinks to one page, where a given one pages
    return chosen;
}

// pack_atlas, the density chosen from the scene where with_density_from_scene
// chooses one and it is finer than the default atlas filled: an auto atlas
// is never coarser than kDefaultResolution² (sets from_scene when finer).
// A chosen density whose charts need a larger square than the default is
// finer than the default filled, which then need not be packed.
Packing pack_atlas_for_scene(const ChartLayout& layout, const AtlasOptions& options, double border_length, double area,
                             bool& from_scene) {
    const AtlasOptions chosen = with_density_from_scene(options, border_length, area);
    from_scene = false;
    if (chosen.texel_density == options.texel_density) return pack_atlas(layout, options);
    const int padding = std::max(0, options.padding);
    auto square = smallest_square(layout, chosen.texel_density, padding, chosen.max_resolution, false);
    if (!square || square->size <= kDefaultResolution) {
        auto filled = pack_at_resolution(layout, kDefaultResolution, padding, 0.0);
        if (filled && filled->density >= chosen.texel_density) return *filled;
    }
    from_scene = true;
    return square ? *square : pack_atlas(layout, chosen);
}

// Each chart's mesh lightmap scale: the largest where a chart spans meshes
// (0 where its meshes have no lightmap: segment_charts keeps those apart).
std::vector<double> chart_mesh_scales(const Scene& scene, const ChartLayout& layout) {
    const std::vector<float> mesh_scale = scene.triangle_lightmap_scales();
    std::vector<double> scale(layout.charts.size(), 0.0);
    for (size_t c = 0; c < layout.charts.size(); ++c)
        for (uint32_t t : layout.charts[c].triangles) scale[c] = std::max(scale[c], double(mesh_scale[t]));
    return scale;
}

// Lays each chart out at its scale: its mesh's lightmap scale (`mesh_scale`,
// chart_mesh_scales), times kUnlitChartScale where flagged in `unlit`
// (fewer texels for one black value) or else its light's (`light_scale`,
// where given: AtlasOptions::light_scales), one texel where its mesh has no
// lightmap; counts them in the report. Returns the lit charts (neither
// unlit nor without a lightmap): their area, and which they are not.
struct LitCharts {
    double area = 0.0;
    std::vector<uint8_t> not_lit;  // per chart: 1 where unlit or without a lightmap
};
LitCharts scale_charts(const Scene& scene, const std::vector<uint8_t>& unlit, const std::vector<double>& mesh_scale,
                       const std::vector<double>& light_scale, ChartLayout& layout, AtlasReport& report) {
    LitCharts lit_charts;
    lit_charts.not_lit.assign(layout.charts.size(), 0);
    double lit = 0.0, dark = 0.0;
    for (size_t c = 0; c < layout.charts.size(); ++c) {
        double area = 0.0, scale = mesh_scale[c];
        for (uint32_t t : layout.charts[c].triangles) area += scene.triangle_area(t);
        const bool unmapped = scale == 0.0;
        const bool dark_chart = !unmapped && !unlit.empty() && unlit[c];
        if (!unmapped) (dark_chart ? dark : lit) += area;
        lit_charts.not_lit[c] = dark_chart || unmapped;
        report.mesh_scaled_charts += scale != 1.0 && !unmapped;
        report.unlit_charts += dark_chart;
        report.unmapped_charts += unmapped;
        if (dark_chart) scale *= kUnlitChartScale;
        if (!light_scale.empty() && !dark_chart && !unmapped) {
            scale *= light_scale[c];
            report.light_scaled_charts += light_scale[c] != 1.0;
        }
        if (unmapped) scale = kUnmappedChartScale;
        if (scale == 1.0) continue;
        layout.shapes[c].size *= scale;
        Tri2* corners = layout.corners_of(c);
        for (size_t i = 0; i < layout.charts[c].triangles.size(); ++i)
            for (glm::dvec2& corner : corners[i]) corner *= scale;
    }
    report.unlit_area_fraction = lit + dark > 0.0 ? dark / (lit + dark) : 0.0;
    lit_charts.area = lit;
    return lit_charts;
}

// About the world size of a texel at the density the scene gets without
// light scales, before it is packed: 1 / texel_density where asked, else
// the side of an equal share of the surface in half of the asked (or
// default) square atlas. Only the pairs' distance of a first look at the
// light depends on it, and their scales only through its ratio to the
// light's own scales (AtlasOptions::light_scales).
double first_look_texel(const Scene& scene, const AtlasOptions& options) {
    if (options.texel_density > 0.0f) return 1.0 / double(options.texel_density);
    double area = 0.0;
    for (size_t t = 0; t < scene.triangles.size(); ++t) area += scene.triangle_area(t);
    const double side = options.resolution > 0 ? options.resolution : kDefaultAtlasResolution;
    return std::sqrt(area / (0.5 * side * side));
}

// Every triangle's corner UVs: its chart's corners turned as packed, scaled
// to the density and offset in the chart's (turned) rectangle as its texel
// mask was rasterized.
CornerUVs chart_corner_uvs(const ChartLayout& layout, const Packing& packing) {
    CornerUVs corner_uv(layout.corners.size());  // one per triangle
    const LightmapPages pages = packing.layout();
    const double d = packing.density;
    const glm::dvec2 atlas(packing.size, pages.total_rows());  // pages stacked top to bottom
    for (size_t c = 0; c < layout.charts.size(); ++c) {
        const Placement& place = packing.at[c];
        const glm::dvec2 size = layout.shapes[c].size, turned = turned_size(size, place.turn);
        const glm::dvec2 lo = glm::dvec2(place.at) + glm::dvec2(0.0, double(place.page) * pages.stride());
        const glm::dvec2 hi = lo + glm::dvec2(chart_rect(turned, d));
        const glm::dvec2 origin = lo + chart_offset(turned, d);
        const std::vector<uint32_t>& triangles = layout.charts[c].triangles;
        for (size_t i = 0; i < triangles.size(); ++i)
            for (size_t k = 0; k < 3; ++k) {
                // The clamp only removes rounding (chart_rect tolerates 1e-9 texel).
                const glm::dvec2 corner = turn_corner(layout.corners_of(c)[i][k], size, place.turn);
                corner_uv[triangles[i]][k] = glm::vec2(glm::clamp(origin + corner * d, lo, hi) / atlas);
            }
    }
    return corner_uv;
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
    ChartLayout layout = lay_out_charts(scene, segment_charts(scene, triangle_adjacency(scene.triangles.size(), shared),
                                                              options.max_chart_angle_degrees, report.triangle_chart));

    std::vector<uint8_t> unlit;
    if (options.find_unlit_charts) unlit = options.find_unlit_charts(report.triangle_chart, layout.charts.size());
    std::vector<double> light;
    if (options.light_scales)
        light =
            options.light_scales(report.triangle_chart, layout.charts.size(), unlit, first_look_texel(scene, options));
    // The border that counts is the lit charts': neither unlit nor without a lightmap.
    const LitCharts lit = scale_charts(scene, unlit, chart_mesh_scales(scene, layout), light, layout, report);
    const double border = chart_border_length(scene, shared, report.triangle_chart, lit.not_lit);
    const Packing packing = pack_atlas_for_scene(layout, options, border, lit.area, report.density_from_scene);
    write_corner_uvs(scene, report.triangle_chart, chart_corner_uvs(layout, packing));

    scene.lightmap_pages = packing.layout();
    report.width = packing.size;
    report.height = scene.lightmap_pages.total_rows();
    report.pages = scene.lightmap_pages;
    report.texel_density = float(packing.density);
    report.border_fraction = border_fraction(border, lit.area, packing.density);
    report.charts = layout.charts.size();
    report.utilisation = utilisation(scene, report.width, report.height);
    return report;
}

int smallest_atlas_resolution(const Scene& scene, const AtlasOptions& options) {
    const TriangleAdjacency adjacency = triangle_adjacency(scene.triangles.size(), scene_shared_edges(scene));
    std::vector<uint32_t> triangle_chart;
    const ChartLayout layout =
        lay_out_charts(scene, segment_charts(scene, adjacency, options.max_chart_angle_degrees, triangle_chart));
    // One texel per chart: a density so small that every chart rounds up to one.
    constexpr double kOneTexel = 1e-12;
    const int padding = std::max(0, options.padding);
    const auto square = smallest_square(layout, kOneTexel, padding, options.max_resolution, true);
    return square ? square->size : 0;
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
