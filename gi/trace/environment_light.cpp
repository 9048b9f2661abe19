#include "trace/environment_light.h"

#include "gpu/context.h"
#include "shaders/buffer_bindings.glsl"

#include <glm/vec4.hpp>

#include <string>
#include <vector>

namespace lf {

namespace {

std::vector<glm::vec4> texels_of(const Environment& environment) {
    if (environment.is_constant()) return {glm::vec4(0.0f)};
    std::vector<glm::vec4> texels;
    texels.reserve(environment.texels.size());
    for (const glm::vec3& t : environment.texels) texels.push_back(glm::vec4(t, 0.0f));
    return texels;
}

}  // namespace

EnvironmentLight::EnvironmentLight(const Environment* environment) {
    static const Environment kBlack;
    const Environment& env = environment ? *environment : kBlack;
    texels_ = GpuBuffer(texels_of(env));
    scale_ = env.is_constant() ? env.constant : glm::vec3(1.0f);  // a map's texels are its radiance
    width_ = uint32_t(env.width);
    height_ = uint32_t(env.height);
    GLint largest = 0;
    glGetIntegerv(GL_MAX_TEXTURE_BUFFER_SIZE, &largest);
    if (uint64_t(width_) * height_ > uint64_t(largest))
        throw GpuError(env.source + ": the environment map's " + std::to_string(width_) + " x " +
                       std::to_string(height_) + " texels are more than this device's " + std::to_string(largest) +
                       " in one buffer texture; give a smaller map");
    glCreateTextures(GL_TEXTURE_BUFFER, 1, &texture_);
    glTextureBuffer(texture_, GL_RGBA32F, texels_.id());
}

EnvironmentLight::~EnvironmentLight() {
    if (texture_) glDeleteTextures(1, &texture_);
}

void EnvironmentLight::bind() const { glBindTextureUnit(LF_TEXTURE_ENVIRONMENT, texture_); }

}  // namespace lf
