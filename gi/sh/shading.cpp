#include "sh/shading.h"

#include "gpu/context.h"
#include "gpu/shader.h"
#include "shaders/buffer_bindings.glsl"
#include "shaders/sh_reference_params.glsl"
#include "trace/environment_light.h"

#include <algorithm>
#include <cmath>

namespace lf {

glm::vec3 sh_irradiance(const ShCoefficients& transfer, const EnvironmentSh& env, int bands) {
    glm::vec3 e(0.0f);
    for (int i = 0; i < bands * bands; ++i) e += transfer[i] * env.coefficients[i];
    return e;
}

std::vector<glm::vec3> reference_irradiance(const Scene& scene, const Tracer& tracer, const Environment& env,
                                            int samples, uint32_t seed) {
    std::vector<glm::vec4> vertices;
    vertices.reserve(2 * scene.positions.size());
    for (size_t v = 0; v < scene.positions.size(); ++v) {
        vertices.push_back(glm::vec4(scene.positions[v], 0.0f));
        vertices.push_back(glm::vec4(glm::normalize(scene.normals[v]), 0.0f));
    }
    GpuBuffer vertex_buffer(vertices), out(scene.positions.size() * sizeof(glm::vec4));
    const EnvironmentLight environment(&env);

    const ComputeProgram program = tracer.program("sh_reference.comp");
    tracer.bind();
    vertex_buffer.bind(LF_BINDING_SH_VERTICES);
    environment.bind();
    out.bind(LF_BINDING_IRRADIANCE);
    ShReferenceParams params{};
    params.vertex_count = uint32_t(scene.positions.size());
    params.seed = seed;
    environment.fill(params);
    out.clear_zero();
    // Slices of a few rays per dispatch: Mesa's llvmpipe ends any shader
    // invocation after 65535 loop iterations in all (LP_MAX_TGSI_LOOP_ITERATIONS),
    // BVH traversal steps included, and would silently drop the rest.
    const int slice = 16;
    params.weight = float(M_PI / samples);
    for (int first = 0, chunk = 0; first < samples; first += slice, ++chunk) {
        params.samples = uint32_t(std::min(slice, samples - first));
        params.chunk = uint32_t(chunk);
        program.use(params);
        program.dispatch_1d(scene.positions.size());
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    }
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    std::vector<glm::vec3> result;
    for (const glm::vec4& e : out.read<glm::vec4>()) result.push_back(glm::vec3(e));
    return result;
}

double band_truncation_error(const std::vector<ShCoefficients>& transfer, const EnvironmentSh& env, int bands) {
    double diff = 0.0, level = 0.0;
    for (const ShCoefficients& t : transfer) {
        const glm::vec3 full = sh_irradiance(t, env, kShMaxBands), cut = sh_irradiance(t, env, bands);
        const double a = (full.r + full.g + full.b) / 3.0, b = (cut.r + cut.g + cut.b) / 3.0;
        diff += (a - b) * (a - b);
        level += a * a;
    }
    return level > 0.0 ? std::sqrt(diff / level) : 0.0;
}

int choose_band_count(const std::vector<ShCoefficients>& transfer, const EnvironmentSh& env, double target) {
    for (int bands = 1; bands < kShMaxBands; ++bands)
        if (band_truncation_error(transfer, env, bands) <= target) return bands;
    return kShMaxBands;
}

}  // namespace lf
