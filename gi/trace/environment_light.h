// The light from beyond the scene on the GPU (shaders/environment.glsl):
// an Environment's equirectangular texels with the CDFs that importance-
// sample them, a buffer texture at texture unit LF_TEXTURE_ENVIRONMENT, and its
// LF_ENVIRONMENT_PARAMS in a program's parameter block. Every program whose
// rays may escape reads it the same way: the radiosity map's gather, the
// probes' capture, the paths of both, and the SH reference.
#pragma once

#include "gpu/shader.h"
#include "sh/environment.h"

#include <glm/vec3.hpp>

#include <cstdint>

namespace lf {

class EnvironmentLight {
public:
    // `environment` null: black (no light from beyond). Reads it once, to
    // upload; the caller keeps it. Throws GpuError for a map over the
    // device's largest buffer texture.
    explicit EnvironmentLight(const Environment* environment = nullptr);
    ~EnvironmentLight();
    EnvironmentLight(const EnvironmentLight&) = delete;
    EnvironmentLight& operator=(const EnvironmentLight&) = delete;

    void bind() const;  // at texture unit LF_TEXTURE_ENVIRONMENT
    template <class Params>
    void fill(Params& p) const {
        p.background_r = scale_.r;
        p.background_g = scale_.g;
        p.background_b = scale_.b;
        p.env_width = width_;
        p.env_height = height_;
        p.env_pdf_scale = pdf_scale_;
    }

private:
    GpuBuffer texels_;  // one texel when there is no map: a texture is always bound
    GLuint texture_ = 0;
    glm::vec3 scale_{0.0f};
    uint32_t width_ = 0, height_ = 0;  // 0 x 0: the uniform sky scale_ (a map of one value too)
    float pdf_scale_ = 0.0f;           // importance sampling's (environment.glsl); 0: none
};

}  // namespace lf
