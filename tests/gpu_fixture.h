// One GL context for a whole test binary. LIGHTFARM_TEST_DEVICE=gpu|cpu|auto
// picks the device (auto by default), so the same suite runs on llvmpipe in
// CI and on the GPU machine.
#pragma once

#include "gpu/context.h"
#include "gpu/shader.h"
#include "shaders/buffer_bindings.glsl"
#include "shaders/check_params.glsl"

#include <glm/vec4.hpp>

#include <cstdlib>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace lf::test {

inline GpuContext& gpu() {
    static std::unique_ptr<GpuContext> context = [] {
        const char* env = std::getenv("LIGHTFARM_TEST_DEVICE");
        return std::make_unique<GpuContext>(parse_device_choice(env ? env : "auto"));
    }();
    return *context;
}

inline std::string example_scene(const std::string& name) {
    const char* env = std::getenv("LIGHTFARM_SCENES");
    return std::string(env ? env : LIGHTFARM_EXAMPLES) + "/" + name;
}

// Runs a *_check.comp program (gi/shaders) on `cases`, `vec4s_per_case`
// vec4 each, with `params` (its item_count set here) and whatever else it
// reads already bound; returns its `results_per_case` vec4 per case. How
// the tests call a GLSL function to compare it with the C++.
inline std::vector<glm::vec4> run_check_program(const ComputeProgram& program, const std::vector<glm::vec4>& cases,
                                                size_t results_per_case, size_t vec4s_per_case = 1,
                                                CheckParams params = {}) {
    if (vec4s_per_case == 0 || cases.size() % vec4s_per_case != 0)
        throw std::invalid_argument("run_check_program: " + std::to_string(cases.size()) +
                                    " vec4 are not whole cases of " + std::to_string(vec4s_per_case));
    const size_t items = cases.size() / vec4s_per_case;
    GpuBuffer in(cases), out(results_per_case * items * sizeof(glm::vec4));
    in.bind(LF_BINDING_CHECK_CASES);
    out.bind(LF_BINDING_CHECK_RESULTS);
    params.item_count = uint32_t(items);
    program.use(params);
    program.dispatch_1d(items);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    return out.read<glm::vec4>();
}

}  // namespace lf::test
