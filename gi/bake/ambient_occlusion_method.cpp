#include "bake/ambient_occlusion_method.h"

#include "bake/atlas_files.h"
#include "atlas/texel_samples.h"

#include <algorithm>
#include <cmath>
#include <memory>

#include "shaders/ambient_occlusion_params.glsl"
#include "shaders/buffer_bindings.glsl"
#include "util/stopwatch.h"

namespace lf {

AmbientOcclusionSettings AmbientOcclusionSettings::from(const protocol::OutputSettings& ao, uint32_t seed,
                                                        const Scene& scene) {
    AmbientOcclusionSettings s;
    const glm::vec3 extent = scene.bounds.extent();
    s.distance = ao.number_or_auto("ao_distance") ? float(*ao.number_or_auto("ao_distance"))
                                                  : kAutoDistanceOfExtent * std::max({extent.x, extent.y, extent.z});
    s.seed = seed;
    return s;
}

namespace {

// Per sample point: position, shading normal, geometric normal (a
// degenerate triangle's point gets the one normal it has, or +z).
std::vector<glm::vec4> sample_points(const TexelSamples& texels) {
    std::vector<glm::vec4> points;
    points.reserve(3 * texels.samples.size());
    for (const TexelSample& s : texels.samples) {
        glm::vec3 g = s.geometric_normal, n = s.normal;
        if (!(glm::dot(n, n) > 0.0f)) n = g;
        if (!(glm::dot(n, n) > 0.0f)) n = glm::vec3(0, 0, 1);
        if (!(glm::dot(g, g) > 0.0f)) g = n;
        points.insert(points.end(), {glm::vec4(s.position, 0.0f), glm::vec4(glm::normalize(n), 0.0f),
                                     glm::vec4(glm::normalize(g), 0.0f)});
    }
    return points;
}

}  // namespace

AmbientOcclusionMethod::AmbientOcclusionMethod(const PreparedScene& prepared, const protocol::BakeSettings& settings)
    : prepared_(prepared),
      settings_(AmbientOcclusionSettings::from(*settings.output("ao"), settings.seed, *prepared.atlas_scene)),
      stop_(stop_rule_from(settings.output("ao")->stop())),
      point_count_(uint32_t(prepared.texels.samples.size())),
      program_(prepared.tracer->program("ambient_occlusion.comp")),
      points_(sample_points(prepared.texels)),
      unoccluded_(std::max<size_t>(1, point_count_) * sizeof(float)) {
    unoccluded_.clear_zero();
    settings_json_ = {
        {"method", "ambient_occlusion"},
        {"distance", settings_.distance},
        {"atlas", atlas_json(prepared.atlas)},
        {"subsamples_per_texel", settings.atlas.subsamples * settings.atlas.subsamples},
        {"seed", settings_.seed},
        {"max_passes", stop_.max_passes},
        {"target_error", stop_.target_error},
        {"time_limit", stop_.time_limit},
    };
}

nlohmann::json AmbientOcclusionMethod::description() const {
    return {{"texels", prepared_.texels.covered_count()}, {"settings", settings_json_}};
}

uint64_t AmbientOcclusionMethod::rays_per_pass() const { return point_count_; }

std::vector<PassStats> AmbientOcclusionMethod::run_passes(int count) {
    const Stopwatch clock;
    const AmbientOcclusionParams params{point_count_, uint32_t(stats_.pass), uint32_t(count), settings_.seed,
                                        settings_.distance};
    program_.use(params);
    prepared_.tracer->bind();
    points_.bind(LF_BINDING_AO_POINTS);
    unoccluded_.bind(LF_BINDING_AO_UNOCCLUDED);
    if (point_count_ > 0) program_.dispatch_1d(point_count_);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    // The error estimate needs every point's count on the CPU (4 bytes a
    // point: 1 GB at 4096² with 16 points a texel): read back only when a
    // target error stops the bake; else wait for the device alone. The
    // error is the batch's last pass's; the snapshots carry it per texel.
    const bool estimate = stop_.target_error > 0.0;
    std::vector<float> unoccluded;
    if (estimate) unoccluded = unoccluded_.read<float>();
    else glFinish();
    const double seconds = clock.seconds();
    std::vector<PassStats> out;
    for (int k = 0; k < count; ++k) {
        stats_.pass += 1;
        stats_.rays += point_count_;
        stats_.seconds += seconds / count;
        stats_.error_estimate.reset();
        if (estimate && k == count - 1) stats_.error_estimate = error_estimate(unoccluded, stats_.pass);
        out.push_back(stats_);
    }
    return out;
}

// A texel's occlusion is the mean of N·c Bernoulli rays (N passes, c
// points): its variance is about p(1-p)/(N·c). The estimate is the RMS of
// those standard errors over the mean occlusion.
double AmbientOcclusionMethod::error_estimate(const std::vector<float>& unoccluded, int passes) const {
    const TexelSamples& texels = prepared_.texels;
    double variance = 0.0, mean = 0.0;
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        double sum = 0.0;
        for (uint32_t k = texels.first_sample[i]; k < texels.first_sample[i + 1]; ++k) sum += unoccluded[k];
        const double rays = double(passes) * texels.sample_count(i);
        const double p = sum / rays;
        variance += p * (1.0 - p) / rays;
        mean += p;
    }
    const double n = double(std::max<size_t>(1, texels.covered_count()));
    return mean > 0.0 ? std::sqrt(variance / n) / (mean / n) : 0.0;
}

FloatImage AmbientOcclusionMethod::image(const std::vector<float>& unoccluded, int passes) const {
    const TexelSamples& texels = prepared_.texels;
    const size_t pixels = size_t(texels.width) * size_t(texels.height);
    std::vector<glm::vec3> ao(pixels, glm::vec3(0.0f)), layers(pixels, glm::vec3(0.0f));  // samples, error, covered
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        double sum = 0.0;
        for (uint32_t k = texels.first_sample[i]; k < texels.first_sample[i + 1]; ++k) sum += unoccluded[k];
        const double rays = double(std::max(1, passes)) * texels.sample_count(i);
        const double p = sum / rays;
        ao[texels.texels[i]] = glm::vec3(float(p));
        layers[texels.texels[i]] = glm::vec3(float(rays), float(std::sqrt(p * (1.0 - p) / rays)), 1.0f);
    }
    dilate(texels, ao);
    FloatImage image;
    image.width = texels.width;
    image.height = texels.height;
    std::vector<float>&r = image.channel("R"), &g = image.channel("G"), &b = image.channel("B");
    std::vector<float>&samples = image.channel("samples"), &error = image.channel("error"),
    &covered = image.channel("covered");
    for (size_t p = 0; p < pixels; ++p) {
        r[p] = g[p] = b[p] = ao[p].x;
        samples[p] = layers[p].x;
        error[p] = layers[p].y;
        covered[p] = layers[p].z;
    }
    image.string_attributes["lightfarm.renderer"] = prepared_.gpu ? prepared_.gpu->info().renderer : "";
    image.string_attributes["lightfarm.settings"] = settings_json_.dump();
    image.number_attributes["lightfarm.pass"] = passes;
    return image;
}

SnapshotWrite AmbientOcclusionMethod::snapshot(const std::filesystem::path& dir, const PassStats& stats) {
    auto unoccluded = std::make_shared<std::vector<float>>(unoccluded_.read<float>());
    return [this, dir, unoccluded, pass = stats.pass] {
        const std::string name = snapshot_file_name("ao", pass, "exr");
        write_exr(dir / name, image(*unoccluded, pass));
        return std::vector<std::string>{name};
    };
}

MethodResult AmbientOcclusionMethod::finish(const std::filesystem::path& dir, const PassStats& stats) {
    auto final_image = std::make_shared<const FloatImage>(image(unoccluded_.read<float>(), stats.pass));
    MethodResult result;
    result.files = write_atlas_exr(dir, "ao.exr", *final_image, prepared_.atlas.pages);
    result.image = std::move(final_image);
    result.manifest = {
        {"settings", settings_json_},
        {"texels", {{"covered", prepared_.texels.covered_count()}}},
        {"result", protocol::to_json(stats)},
        {"files",
         {{"ao.exr",
           "final ambient occlusion: R = G = B = the cosine-weighted unoccluded fraction within the AO distance (1 "
           "open, 0 enclosed); layers samples, error, covered"},
          {"ao.pass-NNNN.exr", "intermediate ambient occlusion snapshots"}}},
    };
    if (prepared_.atlas.pages.count > 1) result.manifest["files"]["ao.page-N.exr"] = page_files_description("ao.exr");
    return result;
}

uint64_t AmbientOcclusionMethod::layout() const {
    const auto& samples = prepared_.texels.samples;
    return hash_bytes(samples.data(), samples.size() * sizeof(TexelSample), hash_vector(prepared_.texels.texels));
}

MethodState AmbientOcclusionMethod::state() const {
    MethodState s;
    s.layout = layout();
    s.stats = stats_;
    s.buffers = {buffer_bytes(unoccluded_)};
    return s;
}

void AmbientOcclusionMethod::restore(const MethodState& s) {
    if (s.layout != layout()) throw MethodStateMismatch("the atlas's sample points are laid out differently");
    restore_buffers({{&unoccluded_, "the sample points' unoccluded counts"}}, s.buffers);
    stats_ = s.stats;
}

}  // namespace lf
