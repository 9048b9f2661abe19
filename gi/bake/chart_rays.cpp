#include "bake/chart_rays.h"

#include <glm/gtc/constants.hpp>

#include <algorithm>
#include <cmath>

namespace lf {

std::vector<ChartPoint> random_chart_points(const Scene& scene, const std::vector<uint32_t>& triangles, int count,
                                            std::mt19937& rng) {
    std::vector<float> area(triangles.size());
    for (size_t k = 0; k < triangles.size(); ++k) area[k] = scene.triangle_area(triangles[k]);
    std::discrete_distribution<size_t> pick(area.begin(), area.end());
    std::uniform_real_distribution<float> uniform(0.0f, 1.0f);
    std::vector<ChartPoint> points;
    for (int p = 0; p < count && !triangles.empty(); ++p) {
        const uint32_t t = triangles[pick(rng)];
        const glm::uvec3 v = scene.triangles[t];
        float b1 = uniform(rng), b2 = uniform(rng);
        if (b1 + b2 > 1.0f) b1 = 1.0f - b1, b2 = 1.0f - b2;
        points.push_back(
            {(1.0f - b1 - b2) * scene.positions[v.x] + b1 * scene.positions[v.y] + b2 * scene.positions[v.z],
             scene.geometric_normal(t), t});
    }
    return points;
}

glm::vec3 cosine_direction(const glm::vec3& n, float u1, float u2) {
    const float r = std::sqrt(u1), phi = 2.0f * glm::pi<float>() * u2;
    const glm::vec3 a = std::abs(n.x) > 0.9f ? glm::vec3(0, 1, 0) : glm::vec3(1, 0, 0);
    const glm::vec3 t = glm::normalize(glm::cross(a, n)), b = glm::cross(n, t);
    return glm::normalize(r * std::cos(phi) * t + r * std::sin(phi) * b + std::sqrt(std::max(0.0f, 1.0f - u1)) * n);
}

std::vector<size_t> punctual_lights_to_try(const Scene& scene, std::mt19937& rng) {
    const size_t n = scene.lights.size();
    std::uniform_real_distribution<float> uniform(0.0f, 1.0f);
    std::vector<size_t> lights;
    for (size_t l = 0; l < std::min(n, kLightsPerPoint); ++l)
        lights.push_back(n <= kLightsPerPoint ? l : size_t(uniform(rng) * float(n)) % n);
    return lights;
}

}  // namespace lf
