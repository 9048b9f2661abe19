// A headless OpenGL 4.5 core context on an EGL device: no window system, no
// display server. One per process (the worker, the CLI, a test).
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

namespace lf {

// Which EGL device to run on: Auto prefers a GPU and falls back to the CPU;
// Gpu may name one GPU by its index among the machine's GPUs (a service
// runs one worker per GPU, each on its own).
struct DeviceChoice {
    enum Kind { Auto, Gpu, Cpu };
    Kind kind = Auto;
    int gpu_index = -1;  // with Gpu: which one; -1 = the first that works
    DeviceChoice(Kind k = Auto, int index = -1) : kind(k), gpu_index(index) {}
};

// "auto" | "gpu" | "gpu:N" | "cpu"; throws std::invalid_argument otherwise.
DeviceChoice parse_device_choice(const std::string& text);

class GpuError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

struct DeviceInfo {
    std::string vendor;        // GL_VENDOR
    std::string renderer;      // GL_RENDERER
    std::string version;       // GL_VERSION
    bool is_software = false;  // Mesa llvmpipe/softpipe
};

// The EGL devices of this machine, without creating contexts.
struct EglDeviceInfo {
    bool software = false;  // Mesa's llvmpipe/softpipe
    int gpu_index = -1;     // index among the hardware devices, -1 for software
};
std::vector<EglDeviceInfo> list_egl_devices();

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
