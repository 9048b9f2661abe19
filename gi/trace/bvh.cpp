#include "trace/bvh.h"

#include <algorithm>
#include <limits>
#include <array>
#include <chrono>
#include <numeric>

namespace lf {

namespace {

constexpr int kBins = 32;
constexpr uint32_t kMaxLeafSize = 8;
constexpr float kTraversalCost = 1.0f;  // relative to one triangle test

struct BuildRef {  // a triangle while building
    Bounds box;
    glm::vec3 centroid;
    uint32_t triangle;
};

struct Range {
    uint32_t begin, end;
    uint32_t count() const { return end - begin; }
};

struct Split {
    int axis = -1;
    float position = 0.0f;
    float cost = std::numeric_limits<float>::max();
};

Bounds bounds_of(const std::vector<BuildRef>& refs, Range r, Bounds* centroids) {
    Bounds b, c;
    for (uint32_t i = r.begin; i < r.end; ++i) {
        b.extend(refs[i].box);
        c.extend(refs[i].centroid);
    }
    *centroids = c;
    return b;
}

// Binned SAH (Wald 2007): bin centroids along each axis, sweep the bins from
// both sides, keep the cheapest plane.
Split find_split(const std::vector<BuildRef>& refs, Range r, const Bounds& centroids) {
    Split best;
    const glm::vec3 extent = centroids.extent();
    for (int axis = 0; axis < 3; ++axis) {
        if (extent[axis] <= 0.0f) continue;
        std::array<Bounds, kBins> bin_box{};
        std::array<uint32_t, kBins> bin_count{};
        const float scale = float(kBins) / extent[axis];
        for (uint32_t i = r.begin; i < r.end; ++i) {
            int b = std::min(kBins - 1, int((refs[i].centroid[axis] - centroids.lo[axis]) * scale));
            bin_box[size_t(b)].extend(refs[i].box);
            ++bin_count[size_t(b)];
        }
        // Right-to-left sweep: area and count of everything right of plane k.
        std::array<float, kBins> right_area{};
        std::array<uint32_t, kBins> right_count{};
        Bounds acc;
        uint32_t n = 0;
        for (int k = kBins - 1; k > 0; --k) {
            acc.extend(bin_box[size_t(k)]);
            n += bin_count[size_t(k)];
            right_area[size_t(k)] = acc.empty() ? 0.0f : acc.surface_area();
            right_count[size_t(k)] = n;
        }
        acc = Bounds{};
        n = 0;
        for (int k = 1; k < kBins; ++k) {
            acc.extend(bin_box[size_t(k - 1)]);
            n += bin_count[size_t(k - 1)];
            if (n == 0 || right_count[size_t(k)] == 0) continue;
            const float cost = acc.surface_area() * float(n) + right_area[size_t(k)] * float(right_count[size_t(k)]);
            if (cost < best.cost) {
                best.cost = cost;
                best.axis = axis;
                best.position = centroids.lo[axis] + float(k) / scale;
            }
        }
    }
    return best;
}

class Builder {
public:
    Builder(std::vector<BuildRef>& refs, Bvh& bvh) : refs_(refs), bvh_(bvh) {}

    // Decides whether `r` becomes a leaf; if not, partitions it and returns the two halves.
    bool split(Range r, const Bounds& box, const Bounds& centroids, size_t depth, Range* left, Range* right) {
        if (r.count() <= 1) return false;
        Split s = find_split(refs_, r, centroids);
        const float leaf_cost = float(r.count());
        const float split_cost = kTraversalCost + s.cost / box.surface_area();
        const bool must_split = r.count() > kMaxLeafSize;
        if (s.axis < 0 || (!must_split && split_cost >= leaf_cost)) {
            if (!must_split) return false;
            // All centroids coincide (or SAH found nothing): split the list in the middle.
            const uint32_t mid = r.begin + r.count() / 2;
            *left = {r.begin, mid};
            *right = {mid, r.end};
            return depth + 1 < size_t(kBvhMaxDepth);
        }
        auto mid_it = std::partition(refs_.begin() + r.begin, refs_.begin() + r.end,
                                     [&](const BuildRef& t) { return t.centroid[s.axis] < s.position; });
        uint32_t mid = uint32_t(mid_it - refs_.begin());
        if (mid == r.begin || mid == r.end) mid = r.begin + r.count() / 2;
        *left = {r.begin, mid};
        *right = {mid, r.end};
        // Past the depth limit the subtree becomes one (large) leaf: rare, and
        // it keeps the GPU stack bounded.
        return depth + 1 < size_t(kBvhMaxDepth);
    }

    // Writes the child slot of `node` for range r and recurses if it is interior.
    void build_child(uint32_t node, bool is_left, Range r, size_t depth) {
        Bounds centroids;
        const Bounds box = bounds_of(refs_, r, &centroids);
        Range a{}, b{};
        const bool interior = split(r, box, centroids, depth, &a, &b);
        uint32_t index, count;
        if (interior) {
            index = uint32_t(bvh_.nodes.size());
            bvh_.nodes.emplace_back();
            count = 0;
        } else {
            index = r.begin;
            count = r.count();
            ++bvh_.stats.leaves;
        }
        BvhNode& n = bvh_.nodes[node];
        if (is_left) {
            n.left_lo = box.lo;
            n.left_hi = box.hi;
            n.left_index = index;
            n.left_count = count;
        } else {
            n.right_lo = box.lo;
            n.right_hi = box.hi;
            n.right_index = index;
            n.right_count = count;
        }
        bvh_.stats.max_depth = std::max(bvh_.stats.max_depth, depth);
        if (interior) {
            build_child(index, true, a, depth + 1);
            build_child(index, false, b, depth + 1);
        }
    }

private:
    std::vector<BuildRef>& refs_;
    Bvh& bvh_;
};

double sah_cost(const Bvh& bvh, const Bounds& root_box) {
    // Expected cost of a random ray that hits the root box: each child box
    // weighted by its area relative to the root.
    const float root_area = std::max(root_box.surface_area(), 1e-30f);
    double cost = kTraversalCost;
    auto area = [](glm::vec3 lo, glm::vec3 hi) {
        Bounds b;
        b.lo = lo;
        b.hi = hi;
        return b.empty() ? 0.0f : b.surface_area();
    };
    for (const BvhNode& n : bvh.nodes) {
        const float al = area(n.left_lo, n.left_hi) / root_area, ar = area(n.right_lo, n.right_hi) / root_area;
        cost += n.left_count ? al * n.left_count : al * kTraversalCost;
        cost += n.right_count ? ar * n.right_count : ar * kTraversalCost;
    }
    return cost;
}

}  // namespace

Bvh build_bvh(const Scene& scene) {
    const auto start = std::chrono::steady_clock::now();
    std::vector<BuildRef> refs;
    refs.reserve(scene.triangles.size());
    for (size_t t = 0; t < scene.triangles.size(); ++t) {
        if (scene.triangle_area(t) <= 0.0f) continue;
        const glm::uvec3 tri = scene.triangles[t];
        BuildRef r;
        for (int k = 0; k < 3; ++k) r.box.extend(scene.positions[tri[k]]);
        r.centroid = r.box.centre();
        r.triangle = uint32_t(t);
        refs.push_back(r);
    }

    Bvh bvh;
    bvh.nodes.emplace_back();  // the root
    BvhNode& root = bvh.nodes[0];
    // An unused child slot: a box at +infinity, which the slab test (it
    // takes min/max of the slabs, so an inverted box would NOT be empty)
    // never enters from any ray. Its index 0 would lead back to the root.
    const glm::vec3 nowhere(std::numeric_limits<float>::infinity());
    root.right_lo = root.right_hi = nowhere;
    Bounds root_box;
    if (!refs.empty()) {
        Builder builder(refs, bvh);
        Bounds centroids;
        root_box = bounds_of(refs, {0, uint32_t(refs.size())}, &centroids);
        Range a{}, b{};
        if (builder.split({0, uint32_t(refs.size())}, root_box, centroids, 0, &a, &b)) {
            builder.build_child(0, true, a, 1);
            builder.build_child(0, false, b, 1);
        } else {
            // Few triangles: the root holds one leaf.
            bvh.nodes[0].left_lo = root_box.lo;
            bvh.nodes[0].left_hi = root_box.hi;
            bvh.nodes[0].left_index = 0;
            bvh.nodes[0].left_count = uint32_t(refs.size());
            bvh.stats.leaves = 1;
        }
    } else {
        root.left_lo = root.left_hi = nowhere;
    }

    bvh.triangles.resize(refs.size());
    for (size_t i = 0; i < refs.size(); ++i) {
        const glm::uvec3 tri = scene.triangles[refs[i].triangle];
        BvhTriangle& out = bvh.triangles[i];
        out.v0 = scene.positions[tri[0]];
        out.v1 = scene.positions[tri[1]];
        out.v2 = scene.positions[tri[2]];
        out.scene_triangle = refs[i].triangle;
        out.pad1 = out.pad2 = 0.0f;
    }
    bvh.stats.nodes = bvh.nodes.size();
    bvh.stats.bytes = bvh.nodes.size() * sizeof(BvhNode) + bvh.triangles.size() * sizeof(BvhTriangle);
    bvh.stats.sah_cost = refs.empty() ? 0.0 : sah_cost(bvh, root_box);
    bvh.stats.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return bvh;
}

}  // namespace lf
