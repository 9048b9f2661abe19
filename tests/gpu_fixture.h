// One GL context for a whole test binary. LIGHTFARM_TEST_DEVICE=gpu|cpu|auto
// picks the device (auto by default), so the same suite runs on llvmpipe in
// CI and on the GPU machine.
#pragma once

#include "gpu/context.h"

#include <cstdlib>
#include <memory>
#include <string>

namespace lf::test {

inline GpuContext& gpu() {
    static std::unique_ptr<GpuContext> context = [] {
        const char* env = std::getenv("LIGHTFARM_TEST_DEVICE");
        return std::make_unique<GpuContext>(parse_device_choice(env ? env : "auto"));
    }();
    return *context;
}

inline std::string shared_scene(const std::string& name) {
    const char* env = std::getenv("LIGHTFARM_SCENES");
    return std::string(env ? env : LIGHTFARM_SHARED_SCENES) + "/" + name;
}

}  // namespace lf::test
