#include "gpu/context.h"

#include <epoxy/egl.h>
#include <epoxy/gl.h>

#include <cstring>
#include <vector>

namespace lf {

DeviceChoice parse_device_choice(const std::string& text) {
    if (text == "auto") return DeviceChoice::Auto;
    if (text == "gpu") return DeviceChoice::Gpu;
    if (text == "cpu") return DeviceChoice::Cpu;
    if (text.rfind("gpu:", 0) == 0 && text.size() > 4 && text.size() < 8 &&
        text.find_first_not_of("0123456789", 4) == std::string::npos)
        return DeviceChoice(DeviceChoice::Gpu, std::stoi(text.substr(4)));
    throw std::invalid_argument("--device must be auto, gpu, gpu:N or cpu, not '" + text + "'");
}

namespace {

struct Candidate {
    EGLDeviceEXT device;
    bool software;
};

bool has_extension(const char* list, const char* name) {
    if (!list) return false;
    const size_t n = std::strlen(name);
    for (const char* p = list; (p = std::strstr(p, name)); p += n)
        if ((p == list || p[-1] == ' ') && (p[n] == ' ' || p[n] == '\0')) return true;
    return false;
}

// Mesa's software device advertises EGL_MESA_device_software; every other
// device (NVIDIA's, a Mesa DRM device) is hardware.
std::vector<Candidate> enumerate_devices() {
    const char* client_ext = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    if (!has_extension(client_ext, "EGL_EXT_device_enumeration") && !has_extension(client_ext, "EGL_EXT_device_base"))
        throw GpuError("EGL: this EGL implementation cannot enumerate devices (no EGL_EXT_device_enumeration)");
    EGLint count = 0;
    if (!eglQueryDevicesEXT(0, nullptr, &count) || count <= 0)
        throw GpuError("EGL: no devices found (is libegl-mesa0 or an NVIDIA driver installed?)");
    std::vector<EGLDeviceEXT> devices(static_cast<size_t>(count));
    eglQueryDevicesEXT(count, devices.data(), &count);
    std::vector<Candidate> out;
    for (EGLint i = 0; i < count; ++i) {
        const char* ext = eglQueryDeviceStringEXT(devices[size_t(i)], EGL_EXTENSIONS);
        out.push_back({devices[size_t(i)], has_extension(ext, "EGL_MESA_device_software")});
    }
    return out;
}

std::string gl_string(GLenum name) {
    const GLubyte* s = glGetString(name);
    return s ? reinterpret_cast<const char*>(s) : "";
}

}  // namespace

std::vector<EglDeviceInfo> list_egl_devices() {
    std::vector<EglDeviceInfo> out;
    int gpus = 0;
    for (const Candidate& c : enumerate_devices()) out.push_back({c.software, c.software ? -1 : gpus++});
    return out;
}

GpuContext::GpuContext(DeviceChoice choice) {
    std::vector<Candidate> candidates = enumerate_devices();
    // Order: hardware first unless the CPU was asked for; one named GPU alone.
    std::vector<Candidate> ordered;
    int gpu = 0;
    for (const Candidate& c : candidates) {
        if (c.software) continue;
        const bool wanted = choice.kind != DeviceChoice::Cpu && (choice.gpu_index < 0 || choice.gpu_index == gpu);
        if (wanted) ordered.push_back(c);
        ++gpu;
    }
    for (const Candidate& c : candidates)
        if (c.software && choice.kind != DeviceChoice::Gpu) ordered.push_back(c);
    if (ordered.empty()) {
        if (choice.kind == DeviceChoice::Cpu) throw GpuError("--device cpu: no software (llvmpipe) EGL device found");
        if (choice.gpu_index >= 0 && gpu > 0)
            throw GpuError("--device gpu:" + std::to_string(choice.gpu_index) + ": this machine has " +
                           std::to_string(gpu) + " GPU(s), numbered from 0");
        throw GpuError("--device gpu: no GPU EGL device found on this machine");
    }

    std::string failures;
    for (const Candidate& c : ordered) {
        EGLDisplay display = eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, c.device, nullptr);
        EGLint major = 0, minor = 0;
        if (display == EGL_NO_DISPLAY || !eglInitialize(display, &major, &minor)) {
            failures += " [device: eglInitialize failed 0x" + std::to_string(eglGetError()) + "]";
            continue;
        }
        eglBindAPI(EGL_OPENGL_API);
        const EGLint context_attribs[] = {
            EGL_CONTEXT_MAJOR_VERSION,           4,       EGL_CONTEXT_MINOR_VERSION, 5, EGL_CONTEXT_OPENGL_PROFILE_MASK,
            EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
        // Surfaceless: compute only, no config needed (EGL_KHR_no_config_context).
        EGLContext context = eglCreateContext(display, EGL_NO_CONFIG_KHR, EGL_NO_CONTEXT, context_attribs);
        if (context == EGL_NO_CONTEXT || !eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context)) {
            failures += " [OpenGL 4.5 core context failed: 0x" + std::to_string(eglGetError()) + "]";
            if (context != EGL_NO_CONTEXT) eglDestroyContext(display, context);
            eglTerminate(display);
            continue;
        }
        display_ = display;
        context_ = context;
        info_.vendor = gl_string(GL_VENDOR);
        info_.renderer = gl_string(GL_RENDERER);
        info_.version = gl_string(GL_VERSION);
        info_.is_software = c.software;
        if (choice.kind == DeviceChoice::Auto && c.software && !failures.empty()) {
            // A GPU was there but unusable: say so rather than silently running 100x slower.
            info_.renderer += " (GPU unusable:" + failures + ")";
        }
        return;
    }
    throw GpuError("EGL: no device gave an OpenGL 4.5 core context:" + failures);
}

GpuContext::~GpuContext() {
    if (display_) {
        eglMakeCurrent(display_, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        eglDestroyContext(display_, context_);
        eglTerminate(display_);
    }
}

void check_gl(const char* what) {
    GLenum err = glGetError();
    if (err == GL_NO_ERROR) return;
    std::string names;
    for (; err != GL_NO_ERROR; err = glGetError()) {
        switch (err) {
        case GL_INVALID_ENUM: names += " GL_INVALID_ENUM"; break;
        case GL_INVALID_VALUE: names += " GL_INVALID_VALUE"; break;
        case GL_INVALID_OPERATION: names += " GL_INVALID_OPERATION"; break;
        case GL_OUT_OF_MEMORY: names += " GL_OUT_OF_MEMORY"; break;
        default: names += " 0x" + std::to_string(err);
        }
    }
    throw GpuError(std::string("OpenGL error in ") + what + ":" + names);
}

}  // namespace lf
