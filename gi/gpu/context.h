// A headless OpenGL 4.5 core context on an EGL device: no window system, no
// display server. One per process (the worker, the CLI, a test).
#pragma once

#include <stdexcept>
#include <string>

namespace lf {

enum class DeviceChoice { Auto, Gpu, Cpu };

// "auto" | "gpu" | "cpu"; throws std::invalid_argument otherwise.
DeviceChoice parse_device_choice(const std::string& text);

class GpuError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

struct DeviceInfo {
    std::string vendor;    // GL_VENDOR
    std::string renderer;  // GL_RENDERER
    std::string version;   // GL_VERSION
    bool is_software = false;  // Mesa llvmpipe/softpipe
};

class GpuContext {
public:
    // Enumerates EGL devices: Auto prefers an NVIDIA (hardware) device and
    // falls back to Mesa's software device; Gpu without a GPU throws GpuError.
    explicit GpuContext(DeviceChoice choice = DeviceChoice::Auto);
    ~GpuContext();
    GpuContext(const GpuContext&) = delete;
    GpuContext& operator=(const GpuContext&) = delete;

    const DeviceInfo& info() const { return info_; }

private:
    void* display_ = nullptr;  // EGLDisplay
    void* context_ = nullptr;  // EGLContext
    DeviceInfo info_;
};

// Throws GpuError naming `what` if the GL error flag is set.
void check_gl(const char* what);

}  // namespace lf
