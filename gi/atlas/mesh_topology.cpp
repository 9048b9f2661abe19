#include "atlas/mesh_topology.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

namespace lf::atlas_detail {

SharedEdges find_shared_edges(const std::vector<glm::uvec3>& triangles, const std::vector<uint32_t>& weld) {
    struct Keyed {
        uint64_t key;
        EdgeRef ref;
    };
    std::vector<Keyed> all;
    all.reserve(triangles.size() * 3);
    for (uint32_t t = 0; t < triangles.size(); ++t)
        for (uint32_t k = 0; k < 3; ++k) {
            uint32_t a = weld[triangles[t][k]], b = weld[triangles[t][(k + 1) % 3]];
            if (a == b) continue;
            if (a > b) std::swap(a, b);
            all.push_back({(uint64_t(a) << 32) | b, {t, k}});
        }
    std::sort(all.begin(), all.end(), [](const Keyed& x, const Keyed& y) {
        return x.key != y.key ? x.key < y.key : x.ref.triangle < y.ref.triangle;
    });

    SharedEdges shared;
    for (size_t i = 0; i < all.size();) {
        size_t j = i + 1;
        while (j < all.size() && all[j].key == all[i].key) ++j;
        if (j - i >= 2) {
            shared.group_start.push_back(uint32_t(shared.edges.size()));
            for (size_t k = i; k < j; ++k) shared.edges.push_back(all[k].ref);
        }
        i = j;
    }
    shared.group_start.push_back(uint32_t(shared.edges.size()));
    return shared;
}

}  // namespace lf::atlas_detail
