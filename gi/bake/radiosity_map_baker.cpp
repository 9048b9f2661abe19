#include "bake/radiosity_map_baker.h"

#include "gpu/context.h"
#include "io/reference_error.h"
#include "shaders/buffer_bindings.glsl"
#include "util/math.h"
#include "util/stopwatch.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <stdexcept>

namespace lf {

const char* to_string(LightSampling sampling) {
    switch (sampling) {
    case LightSampling::Mis: return "mis";
    case LightSampling::Area: return "area";
    case LightSampling::SolidAngle: return "solid-angle";
    }
    return "?";
}

LightSampling parse_light_sampling(const std::string& text) {
    if (text == "mis") return LightSampling::Mis;
    if (text == "area") return LightSampling::Area;
    if (text == "solid-angle") return LightSampling::SolidAngle;
    throw std::invalid_argument("--light-sampling must be mis, area or solid-angle, not '" + text + "'");
}

namespace {

// The passes one dispatch runs: the settings' or passes_per_dispatch_for's,
// as many as fit 256 MiB of texel totals (16 bytes per texel and pass), and
// at least 1 (one pass of the staircase's 4096² atlas needs 176 MB).
int choose_passes_per_dispatch(const RadiosityMapSettings& s, size_t covered_texels) {
    if (s.passes_per_dispatch < 0 || s.passes_per_dispatch > kMaxPassesPerDispatch)
        throw std::invalid_argument("passes per dispatch must be 1 to " + std::to_string(kMaxPassesPerDispatch) +
                                    " (or 0: auto), not " + std::to_string(s.passes_per_dispatch));
    const int wanted = s.passes_per_dispatch > 0 ? s.passes_per_dispatch
                                                 : passes_per_dispatch_for(covered_texels, renderer_is_software());
    const size_t fit = (size_t(256) << 20) / (sizeof(glm::vec4) * std::max<size_t>(1, covered_texels));
    return int(std::clamp<size_t>(fit, 1, size_t(wanted)));
}

// The gather shader's compile-time choices.
ShaderDefines gather_defines(const RadiosityMapSettings& s, int per_dispatch) {
    ShaderDefines defines = {{"LF_LIGHT_SAMPLING", std::to_string(int(s.light_sampling))}};
    // Without the loop over passes, which costs llvmpipe a quarter of its speed.
    if (per_dispatch == 1) defines.emplace_back("LF_ONE_PASS_PER_DISPATCH", "1");
    if (s.scheme == RadiosityScheme::PathTracing) {
        defines.emplace_back("LF_PATH_TRACE", "1");
        defines.emplace_back("LF_EXACT_TEXTURES", "1");  // the reference reads textures where paths land
    }
    if (s.scheme == RadiosityScheme::FinalGather) defines.emplace_back("LF_FINAL_GATHER", "1");
    if (s.directional) defines.emplace_back("LF_DIRECTIONAL", "1");
    return defines;
}

// The publish pass publishes what indirect rays read: albedo x the whole
// value, and under a final gather albedo x the indirect layer too.
ShaderDefines publish_defines(const RadiosityMapSettings& s) {
    if (s.scheme == RadiosityScheme::FinalGather) return {{"LF_FINAL_GATHER", "1"}};
    return {};
}

bool restarts_epochs(RadiosityScheme s) {
    return s == RadiosityScheme::DoublingEpochs || s == RadiosityScheme::FinalGather;
}

}  // namespace

int passes_per_dispatch_for(size_t covered_texels, bool software_renderer) {
    int passes = 1;
    while (!software_renderer && passes < kMaxPassesPerDispatch &&
           size_t(passes) * covered_texels < kTexelPassesPerDispatch)
        passes *= 2;
    return passes;
}

const char* to_string(RadiosityScheme scheme) {
    switch (scheme) {
    case RadiosityScheme::Thesis: return "thesis";
    case RadiosityScheme::DoublingEpochs: return "epochs";
    case RadiosityScheme::FinalGather: return "final-gather";
    case RadiosityScheme::PathTracing: return "pathtrace";
    }
    return "?";
}

RadiosityScheme parse_radiosity_scheme(const std::string& text) {
    if (text == "thesis") return RadiosityScheme::Thesis;
    if (text == "epochs") return RadiosityScheme::DoublingEpochs;
    if (text == "final-gather") return RadiosityScheme::FinalGather;
    if (text == "pathtrace") return RadiosityScheme::PathTracing;
    throw std::invalid_argument("--scheme must be epochs, final-gather, thesis or pathtrace, not '" + text + "'");
}

RadiosityMapBaker::RadiosityMapBaker(const Scene& scene, const TexelSamples& texels, const Tracer& tracer,
                                     const RadiosityMapSettings& settings)
    : tracer_(tracer),
      settings_(settings),
      passes_per_dispatch_(choose_passes_per_dispatch(settings, texels.covered_count())),
      width_(texels.width),
      height_(texels.height),
      gather_(tracer.program("radiosity_gather.comp", gather_defines(settings, passes_per_dispatch_))),
      publish_(tracer.program("radiosity_publish.comp", publish_defines(settings))),
      shading_(scene, settings.environment) {
    if (settings.scheme == RadiosityScheme::PathTracing) surface_textures_.emplace(scene);
    upload_texels(texels);
}

void RadiosityMapBaker::upload_texels(const TexelSamples& texels) {
    covered_count_ = texels.covered_count();
    std::vector<glm::vec4> points;  // radiosity_texels.glsl's sample_points
    points.reserve(2 * texels.samples.size());
    std::vector<glm::uvec4> covered(covered_count_);
    std::vector<glm::vec4> accumulators(LF_TEXEL_ACCUMULATORS * covered_count_, glm::vec4(0.0f));
    covered_atlas_index_ = texels.texels;
    layout_ = hash_vector(texels.first_sample, hash_vector(texels.texels));
    for (size_t i = 0; i < covered_count_; ++i) {
        covered[i] = glm::uvec4(texels.first_sample[i], texels.sample_count(i), texels.texels[i], 0u);
        accumulators[LF_TEXEL_ACCUMULATORS * i + LF_ACC_ALBEDO] = glm::vec4(texels.albedo[i], 0.0f);
        for (uint32_t k = texels.first_sample[i]; k < texels.first_sample[i + 1]; ++k) {
            const TexelSample& s = texels.samples[k];
            // The geometric normal on the shading normal's side: rays leave from there.
            glm::vec3 ng = s.geometric_normal;
            if (glm::dot(ng, s.normal) < 0.0f) ng = -ng;
            points.push_back(glm::vec4(s.position, texels.texel_world_size[i]));
            points.push_back(glm::vec4(ng, pack_unit_vector(s.normal)));
        }
    }
    sample_points_ = GpuBuffer(points);
    covered_ = GpuBuffer(covered);
    accumulators_ = GpuBuffer(accumulators);
    reflected_ = GpuBuffer(size_t(width_) * size_t(height_) * sizeof(glm::vec4));
    reflected_.clear_zero();
    if (settings_.scheme == RadiosityScheme::FinalGather) {
        reflected_indirect_ = GpuBuffer(size_t(width_) * size_t(height_) * sizeof(glm::vec4));
        reflected_indirect_.clear_zero();
    }
    dilation_ = texels.dilation;
    std::vector<glm::uvec2> pairs;
    for (const auto& [to, from] : dilation_) pairs.emplace_back(to, from);
    dilation_pairs_ = GpuBuffer(pairs);
    std::vector<glm::vec4> albedo(size_t(width_) * size_t(height_), glm::vec4(0.0f));
    for (size_t i = 0; i < covered_count_; ++i) albedo[texels.texels[i]] = glm::vec4(texels.albedo[i], 1.0f);
    for (const auto& [to, from] : dilation_) albedo[to] = albedo[from];
    texel_albedo_ = GpuBuffer(albedo);
    if (settings_.directional) {
        directional_ = GpuBuffer(3 * covered_count_ * sizeof(glm::vec4));
        directional_.clear_zero();
    }
    // Two vec4 per work group of the totals' sums, however it is dispatched, in
    // one slot per pass of a batch: as many passes as fit 64 MiB, at most 64
    // (a batch is at most what a GPU does in a few milliseconds).
    const size_t alignment = storage_offset_alignment();
    const size_t group_bytes = 2 * sizeof(glm::vec4) * std::max<size_t>(1, totals_.groups_1d(covered_count_));
    partials_slot_bytes_ = (group_bytes + alignment - 1) / alignment * alignment;
    max_batch_ = int(std::clamp<size_t>((size_t(64) << 20) / partials_slot_bytes_, 1, 64));
    error_partials_ = GpuBuffer(size_t(max_batch_) * partials_slot_bytes_);
    dispatch_ends_ = GpuTimestamps(max_batch_ + 1);
    texel_totals_ = GpuBuffer(size_t(passes_per_dispatch_) * std::max<size_t>(1, covered_count_) * sizeof(glm::vec4));
    active_texels_ = covered_count_;
    rays_per_texel_ =
        uint64_t(1 + shading_.punctual_count() + (shading_.emitter_count() ? settings_.light_samples : 0));
    relocate_samples_inside_geometry(texels.samples.size());
}

// Moves sample points out of geometry, then records each texel's anchor
// (where it gathers) for the leak check of reflected_radiance_at.
void RadiosityMapBaker::relocate_samples_inside_geometry(size_t sample_count) {
    GpuBuffer moved_samples((sample_count + 31) / 32 * sizeof(uint32_t));  // a bit per sample point
    moved_samples.clear_zero();
    const ComputeProgram relocate = tracer_.program("texel_relocate.comp");
    RadiosityParams params = this->params();
    params.sample_count = uint32_t(sample_count);
    relocate.use(params);
    tracer_.bind();
    sample_points_.bind(LF_BINDING_TEXEL_SAMPLE_POINTS);
    moved_samples.bind(LF_BINDING_MOVED_SAMPLES);
    relocate.dispatch_1d(sample_count);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);

    texel_anchors_ = GpuBuffer(size_t(width_) * size_t(height_) * sizeof(glm::vec4));
    texel_anchors_.clear_zero();
    const ComputeProgram anchor = tracer_.program("texel_anchor.comp");
    anchor.use(params);  // the tracer and the sample points are still bound
    covered_.bind(LF_BINDING_COVERED_TEXELS);
    texel_anchors_.bind(LF_BINDING_TEXEL_ANCHORS);
    anchor.dispatch_1d(covered_count_);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    const ComputeProgram wall_check = tracer_.program("texel_wall_check.comp");
    wall_check.use(params);
    wall_check.dispatch_1d(covered_count_);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    count_texels_by_geometry(moved_samples);
    copy_to_dilated_texels(texel_anchors_);
}

// How many texels intersecting geometry touched, for the output to say
// (read back once, before the passes).
void RadiosityMapBaker::count_texels_by_geometry(const GpuBuffer& moved_samples) {
    const std::vector<uint32_t> moved_bits = moved_samples.read<uint32_t>();
    const std::vector<glm::vec4> anchors = texel_anchors_.read<glm::vec4>();
    const std::vector<glm::uvec4> covered = covered_.read<glm::uvec4>();
    for (const glm::uvec4& texel : covered) {
        bool moved = false;
        for (uint32_t s = texel.x; s < texel.x + texel.y; ++s) moved = moved || (moved_bits[s / 32] >> (s % 32) & 1u);
        moved_texels_ += moved ? 1 : 0;
        cut_texels_ += anchors[texel.z].w >= float(LF_ANCHOR_CUT) ? 1 : 0;  // or LF_ANCHOR_NEXT_TO_CUT
    }
}

void RadiosityMapBaker::copy_to_dilated_texels(const GpuBuffer& atlas_buffer) {
    RadiosityParams params = this->params();
    params.pair_count = uint32_t(dilation_.size());
    copy_.use(params);
    atlas_buffer.bind(LF_BINDING_ATLAS_TEXELS);
    dilation_pairs_.bind(LF_BINDING_COPY_PAIRS);
    copy_.dispatch_1d(dilation_.size());
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
}

void RadiosityMapBaker::bind_buffers() const {
    tracer_.bind();
    sample_points_.bind(LF_BINDING_TEXEL_SAMPLE_POINTS);
    covered_.bind(LF_BINDING_COVERED_TEXELS);
    accumulators_.bind(LF_BINDING_TEXEL_ACCUMULATORS);
    reflected_.bind(LF_BINDING_REFLECTED_RADIANCE);
    if (settings_.scheme == RadiosityScheme::FinalGather) reflected_indirect_.bind(LF_BINDING_REFLECTED_INDIRECT);
    shading_.bind();
    texel_anchors_.bind(LF_BINDING_TEXEL_ANCHORS);
    texel_albedo_.bind(LF_BINDING_TEXEL_ALBEDO);
    if (settings_.directional) directional_.bind(LF_BINDING_DIRECTIONAL_ACCUMULATORS);
    if (surface_textures_) surface_textures_->bind();
}

bool RadiosityMapBaker::at_cell_end(int pass) const {
    return pass == 0 || cell_end_after(pass - 1, passes_per_dispatch_) == pass;
}

int cell_end_after(int pass, int passes_per_dispatch) {
    if (pass < 1) return 1;
    const int doubling = int(std::bit_floor(unsigned(pass)));  // the last power of two <= pass
    const int cell = std::clamp(doubling / kPublicationsPerDoubling, 1, passes_per_dispatch);
    return std::min((pass / cell + 1) * cell, 2 * doubling);
}

// What every dispatch of the bake shares; each sets its own fields on top.
RadiosityParams RadiosityMapBaker::params() const {
    RadiosityParams p{};
    shading_.fill(p);
    p.atlas_width = uint32_t(width_);
    p.atlas_height = uint32_t(height_);
    p.covered_count = uint32_t(covered_count_);
    p.seed = settings_.seed;
    p.light_samples = uint32_t(std::max(1, settings_.light_samples));
    p.converged_error = float(settings_.converged_texel_error);
    p.min_samples = 16;
    return p;
}

void RadiosityMapBaker::dispatch_passes(int first_pass, int count, bool end_epoch, int slot) {
    RadiosityParams params = this->params();
    params.first_pass = uint32_t(first_pass);
    params.pass_count = uint32_t(count);
    params.end_epoch = end_epoch ? 1u : 0u;
    params.partials_stride = uint32_t(partials_slot_bytes_ / sizeof(glm::vec4));
    gather_.use(params);
    texel_totals_.bind(LF_BINDING_TEXEL_TOTALS);
    gather_.dispatch_1d(covered_count_);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);

    totals_.use(params);
    error_partials_.bind_range(LF_BINDING_ERROR_PARTIALS, size_t(slot) * partials_slot_bytes_,
                               size_t(count) * partials_slot_bytes_);
    totals_.dispatch_1d(covered_count_);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);  // read back at the batch's end
}

std::vector<PassStats> RadiosityMapBaker::run_passes(int count) {
    if (count < 1 || count > max_batch_)
        throw std::invalid_argument("a batch of " + std::to_string(count) + " passes (1 to " +
                                    std::to_string(max_batch_) + " here)");
    const Stopwatch clock;
    const double seconds_before = stats_.seconds;
    std::vector<int> dispatch_of_pass;  // which dispatch ran each pass of the batch
    dispatch_ends_.mark(0);
    for (int pass = stats_.pass, done = 0, dispatches = 0; done < count; ++dispatches) {
        const int cell_end = cell_end_after(pass, passes_per_dispatch_);
        const int passes = std::min(cell_end - pass, count - done);
        // Epochs end where the pass count reaches a power of two (passes
        // 1 | 2 | 3-4 | 5-8 …), always a cell's end.
        const bool end_epoch = restarts_epochs(settings_.scheme) && std::has_single_bit(unsigned(pass + passes));
        bind_buffers();
        // The first pass reads a black map (the thesis's B^0 = 0), published:
        // where no texel held a value the gather would follow every path
        // to its end (radiosity_gather.comp's gather_at_hit), a pass of path
        // tracing that also hid the thesis scheme's bias.
        if (pass == 0) publish();
        dispatch_passes(pass, passes, end_epoch, done);
        pass += passes;
        if (pass == cell_end) publish();
        dispatch_ends_.mark(dispatches + 1);
        dispatch_of_pass.insert(dispatch_of_pass.end(), size_t(passes), dispatches);
        done += passes;
    }
    // The batch's one wait: its passes' partial sums, read back together.
    std::vector<glm::vec4> partials(size_t(count) * partials_slot_bytes_ / sizeof(glm::vec4));
    error_partials_.download(partials.data(), partials.size() * sizeof(glm::vec4));
    const double wall = clock.seconds();

    std::vector<PassStats> passes;
    for (int k = 0; k < count; ++k) {
        count_pass(totals_of(partials, k));
        // The batch's wall time at its end; the device's clock at the end of
        // the pass's dispatch within it.
        const int ends = dispatch_of_pass[size_t(k)] + 1;
        stats_.seconds = seconds_before + (k + 1 < count ? std::min(wall, dispatch_ends_.seconds(ends)) : wall);
        passes.push_back(stats_);
    }
    return passes;
}

void RadiosityMapBaker::count_pass(const ResolveTotals& totals) {
    // Rays of this pass: every texel that was active when it began, plus
    // path continuations (path tracing) and gathers.
    stats_.rays += rays_per_texel_ * uint64_t(active_texels_) + uint64_t(totals.extra_rays);
    active_texels_ = size_t(totals.active_next);
    ++stats_.pass;
    // Unknown while any texel's delivered estimate rests on one sample (its
    // variance would read 0, not small): passes 1 to 3 with epochs.
    stats_.error_estimate.reset();
    if (totals.unknown == 0.0 && totals.level > 0.0)
        stats_.error_estimate = std::sqrt(totals.variance / totals.covered) / (totals.level / totals.covered);
}

void RadiosityMapBaker::publish() {
    publish_.use(params());
    publish_.dispatch_1d(covered_count_);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    if (settings_.scheme == RadiosityScheme::FinalGather) copy_to_dilated_texels(reflected_indirect_);
    copy_to_dilated_texels(reflected_);  // last: the copy leaves its buffer bound where the gather reads it
}

RadiosityMapBaker::ResolveTotals RadiosityMapBaker::totals_of(const std::vector<glm::vec4>& partials, int slot) const {
    ResolveTotals t;
    const size_t begin = size_t(slot) * partials_slot_bytes_ / sizeof(glm::vec4);
    const size_t groups = totals_.groups_1d(covered_count_);
    for (size_t g = 0; g < groups; ++g) {
        const glm::vec4 a = partials[begin + 2 * g], b = partials[begin + 2 * g + 1];
        t.variance += a.x;
        t.level += a.y;
        t.active_next += a.z;
        t.covered += a.w;
        t.extra_rays += b.x;
        t.unknown += b.y;
    }
    return t;
}

// What a state holds: the accumulators, the L1 sums, and `with_map` (inside
// a cell) the map its passes read, published at its start and no longer
// what the accumulators say; path tracing reads no map.
// (A template for state()'s const buffers and restore()'s writable ones.)
template <class Baker>
auto RadiosityMapBaker::state_buffers(Baker& baker, bool with_map) {
    using Buffer = decltype(&baker.accumulators_);
    std::vector<std::pair<Buffer, std::string>> buffers = {{&baker.accumulators_, "the texels' accumulators"}};
    if (baker.settings_.directional) buffers.emplace_back(&baker.directional_, "the texels' L1 sums");
    if (with_map && baker.settings_.scheme != RadiosityScheme::PathTracing) {
        buffers.emplace_back(&baker.reflected_, "the map the cell's passes read");
        if (baker.settings_.scheme == RadiosityScheme::FinalGather)
            buffers.emplace_back(&baker.reflected_indirect_, "the map's indirect layer the cell's passes read");
    }
    return buffers;
}

MethodState RadiosityMapBaker::state() const {
    MethodState s;
    s.layout = layout_;
    s.stats = stats_;
    s.counters = {int64_t(active_texels_)};
    for (const auto& [buffer, name] : state_buffers(*this, !at_cell_end(stats_.pass)))
        s.buffers.push_back(buffer_bytes(*buffer));
    return s;
}

void RadiosityMapBaker::restore(const MethodState& s) {
    if (s.layout != layout_) throw MethodStateMismatch("the lightmap's texels are laid out differently");
    if (s.counters.size() != 1) throw MethodStateMismatch("not a lightmap's state");
    // A state taken inside a cell holds the map its passes read (state()),
    // told by its buffers: a state of another passes_per_dispatch (a GPU's,
    // resumed on llvmpipe) is taken too.
    const bool with_map =
        s.buffers.size() == state_buffers(*this, true).size() && s.buffers.size() != state_buffers(*this, false).size();
    restore_buffers(state_buffers(*this, with_map), s.buffers);
    active_texels_ = size_t(s.counters[0]);
    stats_ = s.stats;
    // At a cell's end (this baker's) the map is the accumulators' values,
    // published again here exactly as the last pass before the state did.
    if (!with_map || at_cell_end(stats_.pass)) {
        bind_buffers();
        publish();
    }
}

// L1x.*, L1y.*, L1z.*: the mean of each texel's L1 sums over its passes.
void RadiosityMapBaker::add_directional_layers(FloatImage& image, const std::vector<glm::vec4>& sums) const {
    static const char* const axes[3] = {"L1x.", "L1y.", "L1z."};
    static const char* const rgb[3] = {"R", "G", "B"};
    for (int axis = 0; axis < 3; ++axis)
        for (int c = 0; c < 3; ++c) {
            std::vector<float>& layer = image.channel(std::string(axes[axis]) + rgb[c]);
            for (size_t i = 0; i < covered_count_; ++i) {
                const float passes = sums[3 * i].w;
                layer[covered_atlas_index_[i]] = passes > 0.0f ? sums[3 * i + size_t(axis)][c] / passes : 0.0f;
            }
        }
}

RadiosityMapBaker::Readback RadiosityMapBaker::read_back() const {
    return {accumulators_.read<glm::vec4>(),
            settings_.directional ? directional_.read<glm::vec4>() : std::vector<glm::vec4>{}, stats_};
}

FloatImage RadiosityMapBaker::image(const Readback& readback) const {
    const std::vector<glm::vec4>& acc = readback.accumulators;
    const PassStats& stats = readback.stats;
    FloatImage image;
    image.width = width_;
    image.height = height_;
    std::vector<float>* rgb[3] = {&image.channel("R"), &image.channel("G"), &image.channel("B")};
    std::vector<float>* direct[3] = {&image.channel("direct.R"), &image.channel("direct.G"),
                                     &image.channel("direct.B")};
    std::vector<float>* indirect[3] = {&image.channel("indirect.R"), &image.channel("indirect.G"),
                                       &image.channel("indirect.B")};
    std::vector<float>& samples = image.channel("samples");
    std::vector<float>& error = image.channel("error");
    std::vector<float>& lit = image.channel("lit");
    // 1 on the surface's texels, 0 on the dilated ring that only copies them
    // (and everywhere else): what a comparison counts (gi/io/reference_error.h).
    std::vector<float>& covered = image.channel(kCoveredChannel);
    for (size_t i = 0; i < covered_count_; ++i) {
        const glm::vec4 d = acc[LF_TEXEL_ACCUMULATORS * i + LF_ACC_DIRECT],
                        moments = acc[LF_TEXEL_ACCUMULATORS * i + LF_ACC_MOMENTS];
        const glm::vec4 cur = acc[LF_TEXEL_ACCUMULATORS * i + LF_ACC_INDIRECT],
                        prev = acc[LF_TEXEL_ACCUMULATORS * i + LF_ACC_PREVIOUS];
        const glm::vec3 direct_mean = d.w > 0.0f ? glm::vec3(d) / d.w : glm::vec3(0.0f);
        // The indirect estimate with more samples behind it: the running
        // epoch once it has caught up with the previous one.
        const bool use_current = cur.w > 0.0f && cur.w >= prev.w;
        const glm::vec3 ind = use_current ? glm::vec3(cur) / cur.w : glm::vec3(prev);
        const float n = use_current ? cur.w : prev.w;
        auto var_of_mean = [](float sum, float sum_sq, float count) {
            if (count < 2.0f) return 0.0f;
            const float mean = sum / count;
            return std::max(0.0f, sum_sq / count - mean * mean) / (count - 1.0f);
        };
        const float var = var_of_mean(channel_mean(glm::vec3(d)), moments.x, d.w) +
                          (use_current ? var_of_mean(channel_mean(glm::vec3(cur)), moments.y, cur.w) : moments.z);
        const size_t a = covered_atlas_index_[i];
        for (int c = 0; c < 3; ++c) {
            (*rgb[c])[a] = direct_mean[c] + ind[c];
            (*direct[c])[a] = direct_mean[c];
            (*indirect[c])[a] = ind[c];
        }
        samples[a] = n;
        error[a] = std::sqrt(var);
        lit[a] = d.w > 0.0f ? acc[LF_TEXEL_ACCUMULATORS * i + LF_ACC_ALBEDO].w / d.w : 0.0f;
        covered[a] = 1.0f;
    }
    if (!readback.directional.empty()) add_directional_layers(image, readback.directional);
    for (auto& [name, data] : image.channels)
        if (name != kCoveredChannel)
            for (const auto& [to, from] : dilation_) data[to] = data[from];
    image.number_attributes["lightfarm.pass"] = stats.pass;
    image.number_attributes["lightfarm.rays"] = double(stats.rays);
    image.number_attributes["lightfarm.seconds"] = stats.seconds;
    image.number_attributes["lightfarm.errorEstimate"] = stats.error_estimate.value_or(0.0);
    image.string_attributes["lightfarm.scheme"] = to_string(settings_.scheme);
    return image;
}

}  // namespace lf
