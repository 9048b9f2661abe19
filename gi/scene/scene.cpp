#include "scene/scene.h"

#include "scene/weld.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

namespace lf {

glm::vec4 Texture::sample(glm::vec2 uv) const {
    if (width <= 0 || height <= 0 || texels.empty()) return glm::vec4(1.0f);
    // A NaN or huge coordinate must not reach an int conversion (undefined
    // behaviour); wrapping to [0,1) first in double keeps REPEAT exact.
    if (!std::isfinite(uv.x) || !std::isfinite(uv.y)) return fetch(0, 0);
    double u = double(uv.x) - std::floor(double(uv.x));
    double v = double(uv.y) - std::floor(double(uv.y));

    // Texel centres sit at half-integers: texel x covers [x, x+1) / width.
    double x = u * width - 0.5;
    double y = v * height - 0.5;
    double x0f = std::floor(x);
    double y0f = std::floor(y);
    float fx = float(x - x0f);
    float fy = float(y - y0f);
    auto wrap = [](int i, int n) { return ((i % n) + n) % n; };
    int x0 = wrap(int(x0f), width);
    int y0 = wrap(int(y0f), height);
    int x1 = wrap(x0 + 1, width);
    int y1 = wrap(y0 + 1, height);

    glm::vec4 top = glm::mix(fetch(x0, y0), fetch(x1, y0), fx);
    glm::vec4 bottom = glm::mix(fetch(x0, y1), fetch(x1, y1), fx);
    return glm::mix(top, bottom, fy);
}

bool Scene::all_have_lightmap_uvs() const {
    // An empty scene has nothing to bake into, so it does not count as "has UVs".
    return !instances.empty() &&
           std::all_of(instances.begin(), instances.end(), [](const PrimitiveInstance& i) { return i.has_uv1; });
}

size_t Scene::emissive_triangle_count() const {
    return size_t(std::count_if(triangle_material.begin(), triangle_material.end(),
                                [&](uint32_t m) { return materials[m].is_emissive(); }));
}

std::vector<float> Scene::triangle_lightmap_scales() const {
    std::vector<float> scale(triangles.size(), 1.0f);
    for (const PrimitiveInstance& inst : instances)
        std::fill_n(scale.begin() + inst.first_triangle, inst.triangle_count, inst.lightmap_scale);
    return scale;
}

std::vector<uint8_t> Scene::triangles_without_lightmap() const {
    std::vector<uint8_t> without(triangles.size(), 0);
    for (const PrimitiveInstance& inst : instances)
        std::fill_n(without.begin() + inst.first_triangle, inst.triangle_count, inst.has_lightmap() ? 0 : 1);
    return without;
}

float Scene::triangle_area(size_t t) const {
    const glm::uvec3& tri = triangles[t];
    glm::vec3 e1 = positions[tri.y] - positions[tri.x];
    glm::vec3 e2 = positions[tri.z] - positions[tri.x];
    return 0.5f * glm::length(glm::cross(e1, e2));
}

glm::vec3 Scene::geometric_normal(size_t t) const {
    const glm::uvec3& tri = triangles[t];
    glm::vec3 n = glm::cross(positions[tri.y] - positions[tri.x], positions[tri.z] - positions[tri.x]);
    float len = glm::length(n);
    if (!(len > 0.0f) || !std::isfinite(len)) return glm::vec3(0.0f);
    return n / len;
}

namespace {

glm::vec2 interpolate_uv0(const Scene& scene, size_t t, glm::vec2 bary) {
    const glm::uvec3& tri = scene.triangles[t];
    float b0 = 1.0f - bary.x - bary.y;
    return b0 * scene.uv0[tri.x] + bary.x * scene.uv0[tri.y] + bary.y * scene.uv0[tri.z];
}

}  // namespace

glm::vec3 Scene::albedo_at(size_t t, glm::vec2 bary) const {
    const Material& m = materials[triangle_material[t]];
    glm::vec3 albedo(m.base_color);
    if (m.base_color_texture >= 0)
        albedo *= glm::vec3(textures[size_t(m.base_color_texture)].sample(interpolate_uv0(*this, t, bary)));
    return albedo;
}

glm::vec3 Scene::transmittance_at(size_t t, glm::vec2 bary) const {
    const Material& m = materials[triangle_material[t]];
    if (!m.is_see_through()) return glm::vec3(0.0f);
    glm::vec4 base = m.base_color;
    if (m.base_color_texture >= 0)
        base *= textures[size_t(m.base_color_texture)].sample(interpolate_uv0(*this, t, bary));
    float coverage = 1.0f;
    if (m.alpha_mode == Material::AlphaMode::Mask) coverage = base.a >= m.alpha_cutoff ? 1.0f : 0.0f;
    else if (m.alpha_mode == Material::AlphaMode::Blend) coverage = base.a;
    return glm::vec3(1.0f - coverage) + coverage * m.transmission * glm::vec3(base);
}

std::vector<bool> Scene::closed_volumes() const {
    std::vector<bool> closed(materials.size(), false);
    std::vector<std::vector<size_t>> triangles_of(materials.size());
    for (size_t m = 0; m < materials.size(); ++m) closed[m] = materials[m].has_volume();
    for (size_t t = 0; t < triangles.size(); ++t)
        if (closed[triangle_material[t]]) triangles_of[triangle_material[t]].push_back(t);
    for (size_t m = 0; m < materials.size(); ++m) {
        if (!closed[m]) continue;
        // The material's vertices welded as the atlas welds them (scene/weld.h),
        // then each directed edge counted.
        std::vector<glm::vec3> points;
        std::unordered_map<uint32_t, uint32_t> local;  // scene vertex -> index into points
        for (size_t t : triangles_of[m])
            for (int k = 0; k < 3; ++k)
                if (local.try_emplace(triangles[t][k], uint32_t(points.size())).second)
                    points.push_back(positions[triangles[t][k]]);
        const std::vector<uint32_t> weld = weld_positions(points, weld_tolerance(*this));
        const auto id_of = [&](uint32_t v) { return weld[local.at(v)]; };
        std::unordered_map<uint64_t, int> edges;  // (from << 32 | to) -> times met
        for (size_t t : triangles_of[m]) {
            const uint32_t p[3] = {id_of(triangles[t].x), id_of(triangles[t].y), id_of(triangles[t].z)};
            for (int e = 0; e < 3; ++e) ++edges[uint64_t(p[e]) << 32 | p[(e + 1) % 3]];
        }
        closed[m] = !triangles_of[m].empty();
        for (const auto& [edge, count] : edges) {
            const auto back = edges.find(edge << 32 | edge >> 32);
            if (back == edges.end() || back->second != count) {
                closed[m] = false;
                break;
            }
        }
    }
    return closed;
}

glm::vec3 Scene::emission_at(size_t t, glm::vec2 bary) const {
    const Material& m = materials[triangle_material[t]];
    if (!m.is_emissive()) return glm::vec3(0.0f);
    glm::vec3 emission = m.emission;
    if (m.emissive_texture >= 0)
        emission *= glm::vec3(textures[size_t(m.emissive_texture)].sample(interpolate_uv0(*this, t, bary)));
    return emission;
}

namespace {
// The centroids of the n² sub-triangles of a triangle cut into n parts per
// side: equal areas, so their mean is the midpoint rule over the triangle.
template <class F>
glm::vec3 triangle_mean(F value_at) {
    constexpr int n = 4;
    glm::vec3 sum(0.0f);
    for (int i = 0; i < n; ++i)
        for (int j = 0; i + j < n; ++j) {
            sum += value_at(glm::vec2(float(i) + 1.0f / 3.0f, float(j) + 1.0f / 3.0f) / float(n));  // upright
            if (i + j + 1 < n) sum += value_at(glm::vec2(float(i) + 2.0f / 3.0f, float(j) + 2.0f / 3.0f) / float(n));
        }
    return sum / float(n * n);
}
}  // namespace

glm::vec3 Scene::mean_albedo(size_t t) const {
    const Material& m = materials[triangle_material[t]];
    if (m.base_color_texture < 0) return glm::vec3(m.base_color);
    return triangle_mean([&](glm::vec2 bary) { return albedo_at(t, bary); });
}

glm::vec3 Scene::mean_emission(size_t t) const {
    const Material& m = materials[triangle_material[t]];
    if (!m.is_emissive() || m.emissive_texture < 0) return emission_at(t, glm::vec2(1.0f / 3.0f));
    return triangle_mean([&](glm::vec2 bary) { return emission_at(t, bary); });
}

}  // namespace lf
