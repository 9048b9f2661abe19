#include "bake/scene_shading.h"
#include "shaders/buffer_bindings.glsl"
#include "util/math.h"

#include <cmath>

namespace lf {

SceneShading::SceneShading(const Scene& scene, const Environment* environment) : environment_(environment) {
    // Emissive triangles, chosen in proportion to their power (area x radiance).
    std::vector<uint32_t> emitter_triangles;
    std::vector<glm::vec3> emitter_radiance;  // each one's mean (a texture average: computed once)
    std::vector<double> power;
    double total = 0.0;
    for (size_t t = 0; t < scene.triangles.size(); ++t) {
        const Material& m = scene.materials[scene.triangle_material[t]];
        if (!m.is_emissive() || scene.triangle_area(t) <= 0.0f) continue;
        const glm::vec3 radiance = scene.mean_emission(t);
        const double p = double(scene.triangle_area(t)) * double(channel_mean(radiance)) * (m.double_sided ? 2.0 : 1.0);
        if (p <= 0.0) continue;
        emitter_triangles.push_back(uint32_t(t));
        emitter_radiance.push_back(radiance);
        power.push_back(p);
        total += p;
    }

    constexpr size_t kSurfaceVec4s = 4;  // see SurfaceTriangles in lightmap_lookup.glsl
    std::vector<glm::vec4> surfaces(kSurfaceVec4s * std::max<size_t>(scene.triangles.size(), 1), glm::vec4(0.0f));
    const std::vector<uint8_t> without_lightmap = scene.triangles_without_lightmap();
    for (size_t t = 0; t < scene.triangles.size(); ++t) {
        const glm::uvec3 tri = scene.triangles[t];
        const uint32_t flags =
            (scene.materials[scene.triangle_material[t]].double_sided ? LF_TRIANGLE_DOUBLE_SIDED : 0u) |
            (without_lightmap[t] ? LF_TRIANGLE_WITHOUT_LIGHTMAP : 0u);
        surfaces[kSurfaceVec4s * t] = glm::vec4(scene.uv1[tri.x], scene.uv1[tri.y]);
        surfaces[kSurfaceVec4s * t + 1] = glm::vec4(scene.uv1[tri.z], uint_bits(flags), 0.0f);
        surfaces[kSurfaceVec4s * t + 3] = glm::vec4(scene.mean_albedo(t), 0.0f);
    }

    std::vector<glm::vec4> emitters;
    double running = 0.0;
    for (size_t e = 0; e < emitter_triangles.size(); ++e) {
        const uint32_t t = emitter_triangles[e];
        const glm::uvec3 tri = scene.triangles[t];
        const float area = scene.triangle_area(t);
        const float pdf_choose = float(power[e] / total);
        const glm::vec3 radiance = emitter_radiance[e];
        running += power[e];
        const float cdf = e + 1 == emitter_triangles.size() ? 1.0f : float(running / total);
        emitters.push_back(glm::vec4(scene.positions[tri.x], cdf));
        emitters.push_back(glm::vec4(scene.positions[tri.y], pdf_choose));
        emitters.push_back(glm::vec4(scene.positions[tri.z], area));
        const uint32_t double_sided = scene.materials[scene.triangle_material[t]].double_sided ? 1u : 0u;
        emitters.push_back(glm::vec4(radiance, uint_bits(t << 1 | double_sided)));
        surfaces[kSurfaceVec4s * t + 1].w = pdf_choose / area;
        surfaces[kSurfaceVec4s * t + 2] = glm::vec4(radiance, uint_bits(uint32_t(e)));
    }
    emitter_count_ = uint32_t(emitter_triangles.size());
    emitters_ = GpuBuffer(emitters);
    surface_triangles_ = GpuBuffer(surfaces);

    std::vector<glm::vec4> lights;
    for (const PunctualLight& l : scene.lights) {
        const float type = l.type == PunctualLight::Type::Point  ? 0.0f
                           : l.type == PunctualLight::Type::Spot ? 1.0f
                                                                 : 2.0f;
        lights.push_back(glm::vec4(l.position, type));
        lights.push_back(glm::vec4(glm::normalize(l.direction), l.range));
        lights.push_back(glm::vec4(l.intensity, std::cos(l.inner_cone)));
        lights.push_back(glm::vec4(std::cos(l.outer_cone), 0.0f, 0.0f, 0.0f));
    }
    punctual_count_ = uint32_t(scene.lights.size());
    punctual_lights_ = GpuBuffer(lights);
}

void SceneShading::bind() const {
    surface_triangles_.bind(LF_BINDING_SURFACE_TRIANGLES);
    emitters_.bind(LF_BINDING_EMITTERS);
    punctual_lights_.bind(LF_BINDING_PUNCTUAL_LIGHTS);
    environment_.bind();
}

}  // namespace lf
