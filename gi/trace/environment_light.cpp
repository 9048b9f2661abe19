#include "trace/environment_light.h"

#include "gpu/context.h"
#include "shaders/buffer_bindings.glsl"
#include "util/math.h"

#include <glm/vec4.hpp>

#include <algorithm>
#include <cmath>

#include <string>
#include <vector>

namespace lf {

namespace {

// A map of one value everywhere lights as the uniform sky of that value,
// which cosine rays sample as well as anything can.
bool is_uniform(const Environment& e) {
    return e.is_constant() ||
           std::all_of(e.texels.begin(), e.texels.end(), [&](const glm::vec3& t) { return t == e.texels.front(); });
}

// What environment.glsl reads: the texels (rgb) with their row's CDF in w,
// then each row's CDF in x, of luminance (the mean of R, G, B, as the GLSL
// computes it) x sin θ at the row's centre; and the scale that turns a
// texel's weight into a density over solid angle, W H / (2 π² total) (0:
// nothing to sample, a black map).
struct SampledMap {
    std::vector<glm::vec4> texels;
    float pdf_scale = 0.0f;
};

SampledMap sampled_map(const Environment& e) {
    SampledMap out;
    const size_t w = size_t(e.width), h = size_t(e.height);
    out.texels.reserve(w * h + h);
    std::vector<double> row_total(h, 0.0);
    for (size_t y = 0; y < h; ++y) {
        const double sin_centre = std::sin((double(y) + 0.5) / double(h) * kPi);
        double running = 0.0;
        for (size_t x = 0; x < w; ++x) {
            const glm::vec3 t = e.texels[y * w + x];
            running += double(t.r + t.g + t.b) / 3.0 * sin_centre;
            out.texels.push_back(glm::vec4(t, float(running)));
        }
        for (size_t x = 0; x < w; ++x)
            out.texels[y * w + x].w = running > 0.0 ? out.texels[y * w + x].w / float(running) : 0.0f;
        row_total[y] = running;
    }
    double total = 0.0;
    for (double r : row_total) total += r;
    double running = 0.0;
    for (size_t y = 0; y < h; ++y) {
        running += row_total[y];
        out.texels.push_back(glm::vec4(total > 0.0 ? float(running / total) : 0.0f, 0.0f, 0.0f, 0.0f));
    }
    if (total > 0.0) out.pdf_scale = float(double(w) * double(h) / (2.0 * kPi * kPi * total));
    return out;
}

}  // namespace

EnvironmentLight::EnvironmentLight(const Environment* environment) {
    static const Environment kBlack;
    const Environment& env = environment ? *environment : kBlack;
    if (is_uniform(env)) {
        texels_ = GpuBuffer(std::vector<glm::vec4>{glm::vec4(0.0f)});  // a texture is always bound
        scale_ = env.is_constant() ? env.constant : env.texels.front();
    } else {
        GLint largest = 0;
        glGetIntegerv(GL_MAX_TEXTURE_BUFFER_SIZE, &largest);
        if (uint64_t(env.width) * env.height + env.height > uint64_t(largest))
            throw GpuError(env.source + ": the environment map's " + std::to_string(env.width) + " x " +
                           std::to_string(env.height) + " texels are more than this device's " +
                           std::to_string(largest) + " in one buffer texture; give a smaller map");
        SampledMap map = sampled_map(env);
        texels_ = GpuBuffer(map.texels);
        pdf_scale_ = map.pdf_scale;
        scale_ = glm::vec3(1.0f);  // a map's texels are its radiance
        width_ = uint32_t(env.width);
        height_ = uint32_t(env.height);
    }
    glCreateTextures(GL_TEXTURE_BUFFER, 1, &texture_);
    glTextureBuffer(texture_, GL_RGBA32F, texels_.id());
}

EnvironmentLight::~EnvironmentLight() {
    if (texture_) glDeleteTextures(1, &texture_);
}

void EnvironmentLight::bind() const { glBindTextureUnit(LF_TEXTURE_ENVIRONMENT, texture_); }

}  // namespace lf
