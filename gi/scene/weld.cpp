#include "scene/weld.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

namespace lf {

float weld_tolerance(const Scene& scene) {
    Bounds b;
    for (const glm::vec3& p : scene.positions) b.extend(p);
    const float diagonal = glm::length(b.extent());
    return std::max(1e-5f * diagonal, 1e-7f);
}

std::vector<uint32_t> weld_positions(const std::vector<glm::vec3>& positions, float tolerance) {
    std::vector<uint32_t> weld(positions.size());
    if (positions.empty()) return weld;
    Bounds b;
    for (const glm::vec3& p : positions) b.extend(p);

    // Cells 16x the tolerance: most points lie further than the tolerance from
    // every cell face and need to look only in their own cell.
    const double cell = 16.0 * double(tolerance);
    auto cell_of = [&](const glm::vec3& p, int axis) {
        return int64_t(std::floor((double(p[axis]) - b.lo[axis]) / cell));
    };
    auto key = [](int64_t x, int64_t y, int64_t z) {
        return (uint64_t(x) & 0x1FFFFF) | ((uint64_t(y) & 0x1FFFFF) << 21) | ((uint64_t(z) & 0x1FFFFF) << 42);
    };

    // Representatives per cell as singly linked lists through next_rep.
    std::unordered_map<uint64_t, uint32_t> cell_head;
    cell_head.reserve(positions.size());
    std::vector<uint32_t> next_rep(positions.size(), UINT32_MAX);
    const float tolerance2 = tolerance * tolerance;

    for (uint32_t v = 0; v < positions.size(); ++v) {
        const glm::vec3& p = positions[v];
        int64_t c[3];
        int lo[3], hi[3];
        for (int a = 0; a < 3; ++a) {
            c[a] = cell_of(p, a);
            const double inside = (double(p[a]) - b.lo[a]) - double(c[a]) * cell;
            lo[a] = inside < tolerance ? -1 : 0;
            hi[a] = inside > cell - tolerance ? 1 : 0;
        }
        uint32_t found = UINT32_MAX;
        for (int dx = lo[0]; dx <= hi[0] && found == UINT32_MAX; ++dx)
            for (int dy = lo[1]; dy <= hi[1] && found == UINT32_MAX; ++dy)
                for (int dz = lo[2]; dz <= hi[2] && found == UINT32_MAX; ++dz) {
                    auto it = cell_head.find(key(c[0] + dx, c[1] + dy, c[2] + dz));
                    if (it == cell_head.end()) continue;
                    for (uint32_t r = it->second; r != UINT32_MAX; r = next_rep[r]) {
                        const glm::vec3 d = positions[r] - p;
                        if (glm::dot(d, d) <= tolerance2) {
                            found = r;
                            break;
                        }
                    }
                }
        if (found != UINT32_MAX) {
            weld[v] = found;
            continue;
        }
        weld[v] = v;
        auto [it, inserted] = cell_head.try_emplace(key(c[0], c[1], c[2]), v);
        if (!inserted) {
            next_rep[v] = it->second;
            it->second = v;
        }
    }
    return weld;
}

}  // namespace lf
