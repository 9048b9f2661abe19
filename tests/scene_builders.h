// Small scenes built in code for analytic tests: no file, every number known.
#pragma once

#include "scene/scene.h"

#include <glm/glm.hpp>

#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <utility>

namespace lf::test {

// Appends a material; returns its index.
inline uint32_t add_material(Scene& s, glm::vec3 albedo, glm::vec3 emission = glm::vec3(0.0f),
                             bool double_sided = false) {
    Material m;
    m.name = "m" + std::to_string(s.materials.size());
    m.base_color = glm::vec4(albedo, 1.0f);
    m.emission = emission;
    m.double_sided = double_sided;
    s.materials.push_back(m);
    return uint32_t(s.materials.size() - 1);
}

// Appends one primitive instance from positions and triangles (CCW = front);
// normals are the flat geometric normals, lightmap UVs as given (or zero).
inline void add_mesh(Scene& s, const std::vector<glm::vec3>& positions, const std::vector<glm::uvec3>& tris,
                     uint32_t material, const std::vector<glm::vec2>& uv1 = {}) {
    PrimitiveInstance inst;
    inst.node = inst.mesh = int(s.instances.size());
    inst.primitive = 0;
    inst.first_vertex = uint32_t(s.positions.size());
    inst.vertex_count = uint32_t(positions.size());
    inst.first_triangle = uint32_t(s.triangles.size());
    inst.triangle_count = uint32_t(tris.size());
    inst.has_uv1 = !uv1.empty();
    std::vector<glm::vec3> normals(positions.size(), glm::vec3(0.0f));
    for (const glm::uvec3& t : tris) {
        const glm::vec3 n = glm::cross(positions[t.y] - positions[t.x], positions[t.z] - positions[t.x]);
        for (int k = 0; k < 3; ++k) normals[t[k]] += n;
    }
    for (size_t i = 0; i < positions.size(); ++i) {
        s.positions.push_back(positions[i]);
        s.normals.push_back(glm::length(normals[i]) > 0.0f ? glm::normalize(normals[i]) : glm::vec3(0, 1, 0));
        s.uv0.push_back(glm::vec2(0.0f));
        s.uv1.push_back(uv1.empty() ? glm::vec2(0.0f) : uv1[i]);
        s.bounds.extend(positions[i]);
    }
    for (const glm::uvec3& t : tris) {
        s.triangles.push_back(t + glm::uvec3(inst.first_vertex));
        s.triangle_material.push_back(material);
    }
    s.instances.push_back(inst);
}

// Appends a directional light (a sun) shining along `direction` (made unit)
// with `irradiance` W/m² on a plane facing it.
inline void add_sun(Scene& s, glm::vec3 direction, float irradiance) {
    PunctualLight sun;
    sun.type = PunctualLight::Type::Directional;
    sun.direction = glm::normalize(direction);
    sun.intensity = glm::vec3(irradiance);
    s.lights.push_back(sun);
}

// An axis-aligned quad: corner + two edge vectors; front faces along cross(u, v).
inline void add_quad(Scene& s, glm::vec3 corner, glm::vec3 u, glm::vec3 v, uint32_t material,
                     glm::vec4 uv_rect = glm::vec4(0, 0, 1, 1)) {
    add_mesh(s, {corner, corner + u, corner + u + v, corner + v}, {{0, 1, 2}, {0, 2, 3}}, material,
             {{uv_rect.x, uv_rect.y}, {uv_rect.z, uv_rect.y}, {uv_rect.z, uv_rect.w}, {uv_rect.x, uv_rect.w}});
}

// A closed icosphere with shared vertices (every edge shared by exactly two
// triangles), outward-facing.
inline void add_icosphere(Scene& s, glm::vec3 centre, float radius, int subdivisions, uint32_t material) {
    const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
    std::vector<glm::vec3> v = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                                {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
    for (auto& p : v) p = glm::normalize(p);
    std::vector<glm::uvec3> f = {{0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
                                 {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
                                 {3, 8, 9},   {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
    for (int level = 0; level < subdivisions; ++level) {
        std::map<std::pair<uint32_t, uint32_t>, uint32_t> mid;
        auto midpoint = [&](uint32_t a, uint32_t b) {
            auto key = std::minmax(a, b);
            auto it = mid.find(key);
            if (it != mid.end()) return it->second;
            v.push_back(glm::normalize(v[a] + v[b]));
            return mid[key] = uint32_t(v.size() - 1);
        };
        std::vector<glm::uvec3> g;
        for (const auto& tri : f) {
            uint32_t a = midpoint(tri.x, tri.y), b = midpoint(tri.y, tri.z), c = midpoint(tri.z, tri.x);
            g.insert(g.end(), {{tri.x, a, c}, {tri.y, b, a}, {tri.z, c, b}, {a, b, c}});
        }
        f = std::move(g);
    }
    for (auto& p : v) p = centre + radius * p;
    add_mesh(s, v, f, material);
}

// An axis-aligned box [lo, hi] as one mesh of 8 shared vertices and 12
// outward-facing triangles (every edge shared by two triangles).
inline void add_box(Scene& s, glm::vec3 lo, glm::vec3 hi, uint32_t material) {
    std::vector<glm::vec3> v;
    for (int i = 0; i < 8; ++i) v.push_back({i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z});
    const int faces[6][4] = {{0, 2, 6, 4}, {1, 3, 7, 5}, {0, 1, 5, 4}, {2, 3, 7, 6}, {0, 1, 3, 2}, {4, 5, 7, 6}};
    const glm::vec3 centre = 0.5f * (lo + hi);
    std::vector<glm::uvec3> tris;
    for (const auto& f : faces) {
        glm::uvec3 a(f[0], f[1], f[2]), b(f[0], f[2], f[3]);
        const glm::vec3 n = glm::cross(v[a.y] - v[a.x], v[a.z] - v[a.x]);
        if (glm::dot(n, v[a.x] - centre) < 0.0f) {
            std::swap(a.y, a.z);
            std::swap(b.y, b.z);
        }
        tris.push_back(a);
        tris.push_back(b);
    }
    add_mesh(s, v, tris, material);
}

// A flat grid of nx x ny quads (two triangles each) spanning corner + [0,1]·u + [0,1]·v,
// vertices shared, front along cross(u, v).
inline void add_grid(Scene& s, glm::vec3 corner, glm::vec3 u, glm::vec3 v, int nx, int ny, uint32_t material) {
    std::vector<glm::vec3> p;
    for (int j = 0; j <= ny; ++j)
        for (int i = 0; i <= nx; ++i) p.push_back(corner + (float(i) / float(nx)) * u + (float(j) / float(ny)) * v);
    std::vector<glm::uvec3> tris;
    auto at = [&](int i, int j) { return uint32_t(j * (nx + 1) + i); };
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            tris.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
            tris.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
        }
    add_mesh(s, p, tris, material);
}

}  // namespace lf::test
