#include "bake/lightmap_denoiser.h"

#include "atlas/atlas.h"
#include "shaders/buffer_bindings.glsl"
#include "shaders/denoise_params.glsl"
#include "util/stopwatch.h"

#include <glm/glm.hpp>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <unordered_map>

namespace lf {

namespace {

constexpr uint32_t kNoTexel = 0xffffffffu;                     // as lightmap_denoise.comp's NO_TEXEL
const glm::vec3 kLuminanceWeights(0.2126f, 0.7152f, 0.0722f);  // as its luminance()

// Each covered texel's chart: its first sample's triangle's UV island.
std::vector<uint32_t> chart_of_texels(const Scene& scene, const TexelSamples& texels) {
    const std::vector<uint32_t> island = uv_island_of_triangle(scene);
    std::vector<uint32_t> chart(texels.covered_count());
    for (size_t i = 0; i < chart.size(); ++i) chart[i] = island[texels.samples[texels.first_sample[i]].triangle];
    return chart;
}

// Two vec4 per atlas texel: (position, chart bits), (normal, world size),
// each averaged over the texel's samples.
std::vector<glm::vec4> guide_of(const TexelSamples& texels, const std::vector<uint32_t>& chart) {
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
        guide[2 * a] = glm::vec4(position / n, uint_bits(chart[i]));
        guide[2 * a + 1] = glm::vec4(glm::length(normal) > 0.0f ? glm::normalize(normal) : glm::vec3(0.0f),
                                     texels.texel_world_size[i]);
    }
    return guide;
}

// The filter's weights favour alike neighbours, and in a short bake's skewed
// noise a texel that found the light is less alike than one that did not:
// the filtered map came out darker than the raw one (−0.37% over the Cornell
// box at 512 passes, −2.9% at 8: docs/BENCHMARKS.md, "Denoising"). The
// filter is there to move noise between a chart's texels, not light between
// charts or out of the map, so each chart's filtered texels are scaled,
// channel by channel, to the sum of its raw ones: every chart, and so the
// whole map, keeps the raw bake's mean exactly, and what the filter does
// within a chart stays.
void conserve_chart_light(std::vector<glm::vec4>& filtered, const FloatImage& raw, const TexelSamples& texels,
                          const std::vector<uint32_t>& texel_chart) {
    std::unordered_map<uint32_t, std::pair<glm::dvec3, glm::dvec3>> sums;  // chart -> (raw, filtered)
    const auto &r = raw.at("R"), &g = raw.at("G"), &b = raw.at("B");
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        const uint32_t a = texels.texels[i];
        auto& [raw_sum, filtered_sum] = sums[texel_chart[i]];
        raw_sum += glm::dvec3(r[a], g[a], b[a]);
        filtered_sum += glm::dvec3(filtered[a]);
    }
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        const auto& [raw_sum, filtered_sum] = sums[texel_chart[i]];
        for (int c = 0; c < 3; ++c)
            if (filtered_sum[c] > 0.0 && raw_sum[c] > 0.0)
                filtered[texels.texels[i]][c] = float(filtered[texels.texels[i]][c] * (raw_sum[c] / filtered_sum[c]));
    }
}

// Per atlas texel: its chart (kNoTexel where none), as the guide has it.
std::vector<uint32_t> atlas_chart_of(const TexelSamples& texels, const std::vector<uint32_t>& chart) {
    std::vector<uint32_t> atlas_chart(size_t(texels.width) * size_t(texels.height), kNoTexel);
    for (size_t i = 0; i < texels.covered_count(); ++i) atlas_chart[texels.texels[i]] = chart[i];
    return atlas_chart;
}

// The low end of the share of n trials that succeeded, `share` measured:
// Wilson's score interval at z standard deviations (unlike share - z
// sigma, it stays above 0 and below a share of 1 measured on few trials).
double share_at_least(double share, double n, double z) {
    const double z2n = z * z / n;
    return (share + z2n / 2.0 - z * std::sqrt(share * (1.0 - share) / n + z2n / (4.0 * n))) / (1.0 + z2n);
}

}  // namespace

// A texel whose every sample found no light (its "lit" share 0: under other
// geometry, in a contact shadow) beside lit texels: is its 0 sure, or did
// its few paths miss light its neighbours found? Each lit neighbour (the
// 3x3 texels of its chart) says how often a sample there finds light: its
// lit share q, taken at the low end of its uncertainty (three standard
// deviations: among thousands of dark texels some have neighbours that
// found light more often than it is found there by chance). Were the
// texel like that neighbour, its n samples would all be dark with
// probability (1 - q)^n. Under 1e-3 for every neighbour whose light is
// sure (its value over twice its error: one whose few paths found a trace
// of light is as dark as the texel, and lends it none), the 0 is sure
// and the edge-aware steps keep it; where it is alike one of them (a
// texel lit by a quarter of its paths among ones lit by all, early in a
// bake) the filter smooths it as any texel (LightmapDenoiser tests).
// Without this the filter gave texels of grey_white_room under other
// geometry 0.01-0.03 where the path tracer has under 0.0005; a bound from
// the neighbours' means and variances alone (Cantelli's) kept only a
// quarter of them, their light being found by few, bright paths
// (docs/BENCHMARKS.md, "Denoising").
std::vector<uint32_t> LightmapDenoiser::sure_darks(const FloatImage& image) const {
    constexpr double kChance = 1e-3, kDeviations = 3.0;
    const std::vector<float>&lit = image.at("lit"), &r = image.at("R"), &g = image.at("G"), &b = image.at("B"),
          &error = image.at("error");
    const double n = image.number_attributes.at("lightfarm.pass");  // a dark texel never converges: every pass
    std::vector<uint32_t> keep(atlas_chart_.size(), 0u);
    if (n < 1.0) return keep;
    const int width = texels_.width, height = texels_.height;
    for (uint32_t a : texels_.texels) {
        if (lit[a] != 0.0f) continue;
        const int x = int(a % uint32_t(width)), y = int(a / uint32_t(width));
        bool beside_light = false, sure = true;
        for (int dy = -1; dy <= 1 && sure; ++dy)
            for (int dx = -1; dx <= 1 && sure; ++dx) {
                const int qx = x + dx, qy = y + dy;
                if (qx < 0 || qy < 0 || qx >= width || qy >= height) continue;
                const size_t j = size_t(qy) * size_t(width) + size_t(qx);
                const float light = glm::dot(glm::vec3(r[j], g[j], b[j]), kLuminanceWeights);
                if (atlas_chart_[j] != atlas_chart_[a] || lit[j] <= 0.0f || light <= 2.0f * error[j]) continue;
                beside_light = true;
                const double q = std::min(share_at_least(lit[j], n, kDeviations), 1.0);
                sure = q > 0.0 && n * std::log1p(-q) < std::log(kChance);
            }
        if (beside_light && sure) keep[a] = 1u;
    }
    return keep;
}

LightmapDenoiser::LightmapDenoiser(const Scene& atlas_scene, const TexelSamples& texels)
    : texels_(texels),
      texel_chart_(chart_of_texels(atlas_scene, texels)),
      atlas_chart_(atlas_chart_of(texels, texel_chart_)),
      program_("lightmap_denoise.comp"),
      guide_(guide_of(texels, texel_chart_)) {}

std::vector<glm::vec4> LightmapDenoiser::filter(const std::vector<glm::vec4>& colour, int steps, bool luminance_weights,
                                                const GpuBuffer& keep) const {
    GpuBuffer ping(colour), pong(colour.size() * sizeof(glm::vec4));
    guide_.bind(LF_BINDING_DENOISE_GUIDE);
    keep.bind(LF_BINDING_DENOISE_KEEP);
    for (int s = 0; s < steps; ++s) {
        program_.use(
            DenoiseParams{uint32_t(texels_.width), uint32_t(texels_.height), 1 << s, luminance_weights ? 1u : 0u});
        ping.bind(LF_BINDING_DENOISE_IN);
        pong.bind(LF_BINDING_DENOISE_OUT);
        program_.dispatch_1d(colour.size());
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
        std::swap(ping, pong);
    }
    return ping.read<glm::vec4>();  // waits for the GPU
}

// What the edge-aware filter took from a texel is its noise and, where its
// weights could not tell light from noise, some of its light: a lamp pool's
// peak flattened, a chart's brighter noisy part darkened more than the rest
// (which conserve_chart_light then brightens). Measured as the low-frequency
// error (compare --block) against converged references, the filtered map was
// worse than the raw one at every scale of 4 texels and up on the Cornell
// box, monkey and the staircase (docs/BENCHMARKS.md, "Denoising"). So the
// removed part, raw - filtered, is low-passed by kRestoreSteps steps of the
// same filter without its luminance weights (linear in the colour, still
// within charts and across no crease), and added back where it is more than
// the noise a low-pass of the raw noise would leave: positive-part Wiener
// shrinkage, keep = max(0, 1 - var / l^2), with var the low-pass's own
// variance (the filter carries it, sum of k^2 sigma^2) and l its luminance.
void LightmapDenoiser::restore_low_frequencies(std::vector<glm::vec4>& filtered, const std::vector<glm::vec4>& raw,
                                               const GpuBuffer& keep) const {
    std::vector<glm::vec4> removed(raw.size());
    for (size_t p = 0; p < raw.size(); ++p) removed[p] = glm::vec4(glm::vec3(raw[p] - filtered[p]), raw[p].w);
    const std::vector<glm::vec4> low = filter(removed, kRestoreSteps, false, keep);  // linear: keep is not read
    for (uint32_t p : texels_.texels) {
        const float l = glm::dot(glm::vec3(low[p]), kLuminanceWeights);
        float keep = l * l > 0.0f ? std::max(0.0f, 1.0f - low[p].w / (l * l)) : 0.0f;
        // Never more than twice the texel's own standard error: the low-pass
        // reads its neighbours, and a texel the bake is sure of (a contact
        // shadow's 0 with an error of 0, beside lit texels) is to stay as it is.
        const float limit = 2.0f * std::sqrt(std::max(raw[p].w, 0.0f));
        if (keep * std::abs(l) > limit) keep = limit / std::abs(l);
        filtered[p] =
            glm::vec4(glm::max(glm::vec3(filtered[p]) + keep * glm::vec3(low[p]), glm::vec3(0.0f)), filtered[p].w);
    }
}

void LightmapDenoiser::denoise(FloatImage& image) const {
    if (image.width != texels_.width || image.height != texels_.height)
        throw std::invalid_argument("denoise: a " + std::to_string(image.width) + "x" + std::to_string(image.height) +
                                    " image for a " + std::to_string(texels_.width) + "x" +
                                    std::to_string(texels_.height) + " atlas");
    const Stopwatch clock;
    const size_t pixels = size_t(image.width) * size_t(image.height);
    const auto &r = image.at("R"), &g = image.at("G"), &b = image.at("B"), &error = image.at("error");
    std::vector<glm::vec4> colour(pixels);
    for (size_t p = 0; p < pixels; ++p) colour[p] = glm::vec4(r[p], g[p], b[p], error[p] * error[p]);

    const GpuBuffer keep(sure_darks(image));
    std::vector<glm::vec4> filtered = filter(colour, kSteps, true, keep);
    restore_low_frequencies(filtered, colour, keep);
    conserve_chart_light(filtered, image, texels_, texel_chart_);

    for (const char* c : {"R", "G", "B"}) image.channel(std::string("raw.") + c) = image.at(c);
    std::vector<float>* out[3] = {&image.channel("R"), &image.channel("G"), &image.channel("B")};
    for (size_t i = 0; i < texels_.covered_count(); ++i)
        for (int c = 0; c < 3; ++c) (*out[c])[texels_.texels[i]] = filtered[texels_.texels[i]][c];
    for (const auto& [to, from] : texels_.dilation)
        for (int c = 0; c < 3; ++c) (*out[c])[to] = (*out[c])[from];
    image.number_attributes["lightfarm.denoiseSeconds"] = clock.seconds();
}

}  // namespace lf
