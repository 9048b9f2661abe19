#include "trace/bvh.h"

#include "scene/gltf_loader.h"
#include "util/parallel.h"
#include "util/stopwatch.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <future>
#include <limits>
#include <numeric>
#include <string>
#include <system_error>

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

// The binary tree the SAH builds, before it is collapsed into 4-wide nodes.
struct BinaryChild {
    Bounds box;
    uint32_t index = 0;  // node (count 0) or first triangle (count > 0)
    uint32_t count = 0;
};
struct BinaryNode {
    BinaryChild child[2];
    int children = 0;  // 1 only at the root of a scene that is one leaf
};

class BinaryBuilder {
public:
    // `helpers`: how many more threads the build may start (shared by the
    // builders of its subtrees).
    BinaryBuilder(std::vector<BuildRef>& refs, std::vector<BinaryNode>& nodes, std::atomic<int>& helpers)
        : refs_(refs), nodes_(nodes), helpers_(helpers) {}

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

    // The child for range r: a leaf, or a new node built recursively.
    BinaryChild build_child(Range r, size_t depth) {
        BinaryChild c;
        Bounds centroids;
        c.box = bounds_of(refs_, r, &centroids);
        Range a{}, b{};
        if (!split(r, c.box, centroids, depth, &a, &b)) {
            c.index = r.begin;
            c.count = r.count();
            return c;
        }
        c.index = uint32_t(nodes_.size());
        nodes_.emplace_back();
        const auto [left, right] = build_children(a, b, depth + 1);
        nodes_[c.index] = {{left, right}, 2};
        return c;
    }

    // The two children of a node whose triangles were split into a and b.
    // While a thread of the preparation's is free and both halves are
    // large, the halves are built side by side, each into a node list of
    // its own, appended left then right: the nodes are numbered as one
    // thread numbers them (depth first, left first), so the tree does not
    // depend on the thread count.
    std::array<BinaryChild, 2> build_children(Range a, Range b, size_t depth) {
        constexpr uint32_t kParallelTriangles = 4096;  // fewer take less than a thread's start-up
        if (std::min(a.count(), b.count()) < kParallelTriangles || !take_helper())
            return {build_child(a, depth), build_child(b, depth)};
        std::vector<BinaryNode> left_nodes, right_nodes;
        std::future<BinaryChild> right_child;
        try {
            right_child = std::async(std::launch::async, [&] {
                // refs_ is shared: a and b are apart.
                const BinaryChild child = BinaryBuilder(refs_, right_nodes, helpers_).build_child(b, depth);
                ++helpers_;
                return child;
            });
        } catch (const std::system_error&) {  // no thread to be had: this one builds both
            ++helpers_;
            return {build_child(a, depth), build_child(b, depth)};
        }
        BinaryChild left = BinaryBuilder(refs_, left_nodes, helpers_).build_child(a, depth);
        BinaryChild right = right_child.get();
        append_subtree(left_nodes, left);
        append_subtree(right_nodes, right);
        return {left, right};
    }

private:
    // A helper thread, if one of the preparation's is free.
    bool take_helper() {
        for (int free = helpers_; free > 0;)
            if (helpers_.compare_exchange_weak(free, free - 1)) return true;
        return false;
    }

    // Appends a subtree numbered from 0 after this builder's nodes,
    // renumbering its references to them and `root`'s.
    void append_subtree(std::vector<BinaryNode>& subtree, BinaryChild& root) {
        const auto offset = uint32_t(nodes_.size());
        for (BinaryNode& n : subtree)
            for (int k = 0; k < n.children; ++k)
                if (n.child[k].count == 0) n.child[k].index += offset;
        if (root.count == 0) root.index += offset;
        nodes_.insert(nodes_.end(), subtree.begin(), subtree.end());
    }

    std::vector<BuildRef>& refs_;
    std::vector<BinaryNode>& nodes_;
    std::atomic<int>& helpers_;
};

// The step of an axis of a node's box: the smallest power of two 2^e with
// which 255 steps span `extent`, as the biased exponent of the float 2^e
// (1 to 254: 2^-126 to 2^127; 255 2^e is exact in double).
uint32_t step_exponent(double extent) {
    int e = extent > 0.0 ? std::max(-126, std::ilogb(extent) - 8) : -126;  // 255 2^e < extent here, or e = -126
    while (std::ldexp(255.0, e) < extent) ++e;                             // at most twice
    return uint32_t(e + 127);
}

// Node `index`'s children, their boxes quantized to its own (see BvhNode).
// Each plane is found in double: the difference of two floats is exact there
// (unless their magnitudes are 2^29 apart) and so is a division by a power
// of two, so rounding the low planes down and the high ones up gives boxes
// that contain their children.
BvhNode quantized_node(const std::vector<BinaryChild>& children, const glm::uvec4& index) {
    BvhNode node;
    node.index = index;
    if (children.empty()) return node;  // the root of an empty scene
    Bounds box;
    for (const BinaryChild& c : children) box.extend(c.box);
    node.origin = box.lo;
    for (int a = 0; a < 3; ++a) {
        const uint32_t exponent = step_exponent(double(box.hi[a]) - double(box.lo[a]));
        node.step_exponents |= exponent << (8 * a);
        const double step = std::ldexp(1.0, int(exponent) - 127);
        for (size_t k = 0; k < children.size(); ++k) {
            const double lo = std::floor((double(children[k].box.lo[a]) - double(box.lo[a])) / step);
            const double hi = std::ceil((double(children[k].box.hi[a]) - double(box.lo[a])) / step);
            node.planes[2 * a] |= uint32_t(std::clamp(lo, 0.0, 255.0)) << (8 * k);
            node.planes[2 * a + 1] |= uint32_t(std::clamp(hi, 0.0, 255.0)) << (8 * k);
        }
    }
    for (size_t k = 0; k < children.size(); ++k) node.counts[k / 2] |= children[k].count << (16 * (k % 2));
    return node;
}

// Collapses binary node `from` (and its subtree) into 4-wide node `to` of
// `bvh`: starting from its two children, the interior child of largest
// surface area (the one a ray most likely enters) is replaced by its own two
// children until four fill the node or only leaves are left.
void collapse(const std::vector<BinaryNode>& binary, uint32_t from, uint32_t to, size_t depth, Bvh& bvh) {
    std::vector<BinaryChild> children(binary[from].child, binary[from].child + binary[from].children);
    while (children.size() < size_t(kBvhWidth)) {
        auto widest = children.end();
        for (auto c = children.begin(); c != children.end(); ++c)
            if (c->count == 0 && (widest == children.end() || c->box.surface_area() > widest->box.surface_area()))
                widest = c;
        if (widest == children.end()) break;
        const BinaryNode& opened = binary[widest->index];
        *widest = opened.child[0];
        children.insert(widest + 1, opened.child[1]);
    }
    glm::uvec4 index(0);
    std::vector<std::pair<uint32_t, uint32_t>> interior;  // (binary node, 4-wide node)
    for (size_t k = 0; k < children.size(); ++k) {
        const BinaryChild& c = children[k];
        if (c.count > 0) {
            index[k] = c.index;
            ++bvh.stats.leaves;
        } else {
            index[k] = uint32_t(bvh.nodes.size());
            interior.emplace_back(c.index, index[k]);
            bvh.nodes.emplace_back();
        }
    }
    bvh.nodes[to] = quantized_node(children, index);
    bvh.stats.max_depth = std::max(bvh.stats.max_depth, depth);
    for (const auto& [binary_node, wide_node] : interior) collapse(binary, binary_node, wide_node, depth + 1, bvh);
}

double sah_cost(const Bvh& bvh, const Bounds& root_box) {
    // Expected cost of a random ray that hits the root box: each child box
    // weighted by its area relative to the root.
    const float root_area = std::max(root_box.surface_area(), 1e-30f);
    double cost = kTraversalCost;
    for (const BvhNode& n : bvh.nodes) {
        for (int k = 0; k < kBvhWidth; ++k) {
            if (!n.child_used(k)) continue;
            const float area = n.child_box(k).surface_area() / root_area;
            cost += n.count(k) ? area * float(n.count(k)) : area * kTraversalCost;
        }
    }
    return cost;
}

// Rounds outwards: the float at or below (above) x.
float float_at_or_below(double x) {
    const float f = float(x);
    return double(f) > x ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
}
float float_at_or_above(double x) {
    const float f = float(x);
    return double(f) < x ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
}

}  // namespace

Bounds BvhNode::child_box(int c) const {
    Bounds b;
    for (int a = 0; a < 3; ++a) {
        const double step = std::ldexp(1.0, int((step_exponents >> (8 * a)) & 0xffu) - 127);
        b.lo[a] = float_at_or_below(origin[a] + step * double((planes[2 * a] >> (8 * c)) & 0xffu));
        b.hi[a] = float_at_or_above(origin[a] + step * double((planes[2 * a + 1] >> (8 * c)) & 0xffu));
    }
    return b;
}

Bvh build_bvh(const Scene& scene) {
    const Stopwatch clock;
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

    // The binary tree; its root always has a node, even over one leaf or none.
    std::vector<BinaryNode> binary(1);
    Bounds root_box;
    if (!refs.empty()) {
        std::atomic<int> helpers{int(preparation_threads()) - 1};
        BinaryBuilder builder(refs, binary, helpers);
        Bounds centroids;
        root_box = bounds_of(refs, {0, uint32_t(refs.size())}, &centroids);
        Range a{}, b{};
        if (builder.split({0, uint32_t(refs.size())}, root_box, centroids, 0, &a, &b)) {
            const auto [left, right] = builder.build_children(a, b, 1);
            binary[0] = {{left, right}, 2};
        } else {
            binary[0] = {{BinaryChild{root_box, 0, uint32_t(refs.size())}}, 1};  // few triangles: one leaf
        }
    }
    // A leaf's count has 16 bits (BvhNode). Only the depth limit makes a
    // larger one, on geometry the SAH splits one triangle at a time.
    for (const BinaryNode& n : binary)
        for (int k = 0; k < n.children; ++k)
            if (n.child[k].count > kBvhMaxLeafTriangles)
                throw SceneError(scene.source + ": " + std::to_string(n.child[k].count) +
                                 " triangles are left in one leaf of the ray tracing tree at its depth limit (" +
                                 std::to_string(kBvhMaxDepth) + "); a leaf holds at most " +
                                 std::to_string(kBvhMaxLeafTriangles));
    Bvh bvh;
    bvh.nodes.emplace_back();  // the root
    collapse(binary, 0, 0, 1, bvh);

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
    bvh.stats.build_seconds = clock.seconds();
    return bvh;
}

}  // namespace lf
