#include "bake/lightmap_denoiser.h"

#include "atlas/atlas.h"
#include "shaders/buffer_bindings.glsl"
#include "shaders/denoise_params.glsl"

#include <glm/glm.hpp>

#include <chrono>
#include <stdexcept>

namespace lf {

namespace {

constexpr uint32_t kNoTexel = 0xffffffffu;  // as lightmap_denoise.comp's NO_TEXEL

// Two vec4 per atlas texel: (position, chart bits), (normal, world size),
// each averaged over the texel's samples (the chart is its first sample's).
std::vector<glm::vec4> guide_of(const Scene& scene, const TexelSamples& texels) {
    const std::vector<uint32_t> chart = uv_island_of_triangle(scene);
    std::vector<glm::vec4> guide(2 * size_t(texels.width) * size_t(texels.height), glm::vec4(0.0f));
    for (size_t a = 0; a < guide.size() / 2; ++a) guide[2 * a].w = uint_bits(kNoTexel);
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        glm::vec3 position(0.0f), normal(0.0f);
        for (uint32_t k = texels.first_sample[i]; k < texels.first_sample[i + 1]; ++k) {
            position += texels.samples[k].position;
            normal += texels.samples[k].normal;
        }
        const size_t a = texels.texels[i];
        const float n = float(texels.sample_count(i));
        guide[2 * a] = glm::vec4(position / n, uint_bits(chart[texels.samples[texels.first_sample[i]].triangle]));
        guide[2 * a + 1] = glm::vec4(glm::length(normal) > 0.0f ? glm::normalize(normal) : glm::vec3(0.0f),
                                     texels.texel_world_size[i]);
    }
    return guide;
}

}  // namespace

LightmapDenoiser::LightmapDenoiser(const Scene& atlas_scene, const TexelSamples& texels)
    : texels_(texels), program_("lightmap_denoise.comp"), guide_(guide_of(atlas_scene, texels)) {}

void LightmapDenoiser::denoise(FloatImage& image) const {
    if (image.width != texels_.width || image.height != texels_.height)
        throw std::invalid_argument("denoise: a " + std::to_string(image.width) + "x" + std::to_string(image.height) +
                                    " image for a " + std::to_string(texels_.width) + "x" +
                                    std::to_string(texels_.height) + " atlas");
    const auto start = std::chrono::steady_clock::now();
    const size_t pixels = size_t(image.width) * size_t(image.height);
    const auto &r = image.at("R"), &g = image.at("G"), &b = image.at("B"), &error = image.at("error");
    std::vector<glm::vec4> colour(pixels);
    for (size_t p = 0; p < pixels; ++p) colour[p] = glm::vec4(r[p], g[p], b[p], error[p] * error[p]);

    GpuBuffer ping(colour), pong(pixels * sizeof(glm::vec4));
    guide_.bind(LF_BINDING_DENOISE_GUIDE);
    for (int s = 0; s < kSteps; ++s) {
        program_.use(DenoiseParams{uint32_t(image.width), uint32_t(image.height), 1 << s});
        ping.bind(LF_BINDING_DENOISE_IN);
        pong.bind(LF_BINDING_DENOISE_OUT);
        program_.dispatch_1d(pixels);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
        std::swap(ping, pong);
    }
    const std::vector<glm::vec4> filtered = ping.read<glm::vec4>();  // waits for the GPU

    for (const char* c : {"R", "G", "B"}) image.channel(std::string("raw.") + c) = image.at(c);
    std::vector<float>* out[3] = {&image.channel("R"), &image.channel("G"), &image.channel("B")};
    for (size_t i = 0; i < texels_.covered_count(); ++i)
        for (int c = 0; c < 3; ++c) (*out[c])[texels_.texels[i]] = filtered[texels_.texels[i]][c];
    for (const auto& [to, from] : texels_.dilation)
        for (int c = 0; c < 3; ++c) (*out[c])[to] = (*out[c])[from];
    image.number_attributes["lightfarm.denoiseSeconds"] =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace lf
