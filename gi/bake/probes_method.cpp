#include "bake/probes_method.h"

#include "bake/bake_job.h"
#include "probes/probe_eval.h"
#include "shaders/buffer_bindings.glsl"
#include "util/stopwatch.h"

#include <algorithm>
#include <cmath>
#include <memory>

namespace lf {

namespace {

uint64_t capture_texels(size_t probes, int r) { return uint64_t(probes) * 6u * uint64_t(r) * uint64_t(r); }

}  // namespace

ProbesSettings ProbesSettings::from(const protocol::OutputSettings& o) {
    ProbesSettings p;
    for (const nlohmann::json& point : o.values.at("probe_positions"))
        p.positions.emplace_back(point["position"][0].get<float>(), point["position"][1].get<float>(),
                                 point["position"][2].get<float>());
    p.spacing = o.number_or_auto("probe_spacing");
    p.res = o.integer("probe_res");
    p.m = o.integer("probe_m");
    return p;
}

protocol::BakeSettings probes_at(const std::vector<glm::vec3>& points, int r, int m, uint32_t seed) {
    nlohmann::json positions = nlohmann::json::array();
    for (const glm::vec3& p : points) positions.push_back({{"position", {p.x, p.y, p.z}}});
    return protocol::parse_bake_settings(
        {{"outputs", {{"probes", {{"probe_positions", positions}, {"probe_res", r}, {"probe_m", m}}}}},
         {"seed", seed}});
}

std::vector<glm::vec3> ProbesMethod::place(const Scene& scene, const ProbesSettings& settings, float* spacing) {
    *spacing = 0.0f;
    std::vector<glm::vec3> points;
    if (!settings.positions.empty()) {
        points = settings.positions;
        return points;
    }
    if (!scene.probe_points.empty()) return scene.probe_points;  // the file's nodes marked lightfarm_probe
    // A grid of cell centres over the bounds; auto spacing: a quarter of the
    // largest extent (4 probes along it).
    const glm::vec3 extent = scene.bounds.extent();
    const float largest = std::max({extent.x, extent.y, extent.z});
    const float step = settings.spacing ? float(*settings.spacing) : largest / 4.0f;
    if (!(step > 0.0f)) return points;
    *spacing = step;
    const std::array<uint64_t, 3> n = protocol::probe_grid_counts({extent.x, extent.y, extent.z}, step);
    const uint64_t total = n[0] * n[1] * n[2];
    if (total > protocol::kMaxProbes)
        throw BakeInputError("probes: a grid at " + std::to_string(step) + " m spacing has " + std::to_string(total) +
                             " probes, more than " + std::to_string(protocol::kMaxProbes) + "; raise --probe-spacing");
    const glm::ivec3 counts{int(n[0]), int(n[1]), int(n[2])};
    const glm::vec3 lo = scene.bounds.centre() - 0.5f * glm::vec3(counts) * step;
    for (int z = 0; z < counts.z; ++z)
        for (int y = 0; y < counts.y; ++y)
            for (int x = 0; x < counts.x; ++x) points.push_back(lo + (glm::vec3(x, y, z) + 0.5f) * step);
    return points;
}

ProbesMethod::ProbesMethod(const PreparedScene& prepared, const protocol::BakeSettings& settings)
    : prepared_(prepared),
      settings_(ProbesSettings::from(*settings.output("probes"))),
      stop_(stop_rule_from(settings.output("probes")->stop())),
      seed_(settings.seed),
      shading_(prepared.atlas_scene ? *prepared.atlas_scene : prepared.scene,
               prepared.environment ? &*prepared.environment : nullptr),
      surface_textures_(prepared.atlas_scene ? *prepared.atlas_scene : prepared.scene),
      capture_(prepared.tracer->program("probe_capture.comp", {{"LF_EXACT_TEXTURES", "1"}})) {
    positions_ = place(prepared.scene, settings_, &spacing_);
    if (positions_.empty())
        throw BakeInputError(prepared.file.filename().string() + ": probes: no point to place a probe at");
    const uint64_t texels = capture_texels(positions_.size(), settings_.res);
    if (texels > protocol::kMaxCaptureTexels)
        throw BakeInputError("probes: " + std::to_string(positions_.size()) + " probes at --probe-res " +
                             std::to_string(settings_.res) + " are " + std::to_string(texels) +
                             " capture texels, more than " + std::to_string(protocol::kMaxCaptureTexels) +
                             "; lower --probe-res or place fewer probes");
    moved_from_.assign(positions_.size(), std::nullopt);
    std::vector<glm::vec4> points;
    for (const glm::vec3& p : positions_) points.emplace_back(p, 0.0f);
    positions_buffer_ = GpuBuffer(points);
    texels_ = GpuBuffer(size_t(texels) * 2 * sizeof(glm::vec4));
    texels_.clear_zero();
    rays_ = GpuBuffer(std::vector<uint32_t>{0u});
    if (spacing_ > 0.0f) move_away_from_surfaces();
    corner_distances_ = trace_grid_distances(false);
    centre_distances_ = trace_grid_distances(true);
}

// What the capture and the corner rays share; each sets its count on top.
ProbesParams ProbesMethod::params() const {
    ProbesParams p{};
    shading_.fill(p);
    p.resolution = uint32_t(settings_.res);
    p.pass = uint32_t(stats_.pass);
    p.seed = seed_;
    p.m = uint32_t(settings_.m);
    p.miss_distance = kMissDistance;
    return p;
}

std::vector<float> ProbesMethod::trace_grid_distances(bool centres) const {
    const size_t side = size_t(settings_.m) + (centres ? 0 : 1), count = positions_.size() * 6 * side * side;
    GpuBuffer corners(count * sizeof(float));
    const ComputeProgram program = centres
                                       ? prepared_.tracer->program("probe_corners.comp", {{"LF_TEXEL_CENTRES", "1"}})
                                       : prepared_.tracer->program("probe_corners.comp");
    prepared_.tracer->bind();
    positions_buffer_.bind(LF_BINDING_PROBE_POSITIONS);
    corners.bind(LF_BINDING_PROBE_CORNERS);
    ProbesParams params = this->params();
    params.corner_count = uint32_t(count);
    program.use(params);
    program.dispatch_1d(count);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    return corners.read<float>();
}

void ProbesMethod::move_away_from_surfaces() {
    const float clearance = std::min(kClearance, 0.25f * spacing_);
    const int m = settings_.m;
    const size_t side = size_t(m) + 1, per_probe = 6 * side * side;
    for (int step = 0; step < 3; ++step) {
        const std::vector<float> distances = trace_grid_distances(false);
        bool moved = false;
        for (size_t k = 0; k < positions_.size(); ++k) {
            size_t nearest = 0;
            for (size_t c = 1; c < per_probe; ++c)
                if (distances[k * per_probe + c] < distances[k * per_probe + nearest]) nearest = c;
            const float d = distances[k * per_probe + nearest];
            if (!(d < clearance)) continue;
            const int face = int(nearest / (side * side)), b = int(nearest % (side * side) / side),
                      a = int(nearest % side);
            if (!moved_from_[k]) moved_from_[k] = positions_[k];
            positions_[k] -= cube_direction(face, float(a) / float(m), float(b) / float(m)) * (clearance - d);
            moved = true;
        }
        if (!moved) return;
        std::vector<glm::vec4> points;
        for (const glm::vec3& p : positions_) points.emplace_back(p, 0.0f);
        positions_buffer_ = GpuBuffer(points);
    }
}

nlohmann::json ProbesMethod::description() const {
    return {{"probes", positions_.size()},
            {"settings",
             {{"method", "robust_probes"},
              {"placement", !settings_.positions.empty()            ? "explicit"
                            : !prepared_.scene.probe_points.empty() ? "gltf nodes"
                                                                    : "grid"},
              {"spacing", spacing_},
              {"capture_resolution", settings_.res},
              {"m", settings_.m},
              {"radiance", "emission + reflected light traced as paths from the hit point"},
              {"max_passes", stop_.max_passes},
              {"target_error", stop_.target_error},
              {"time_limit", stop_.time_limit},
              {"seed", seed_}}}};
}

// A path per capture texel (its bounces' rays come on top).
uint64_t ProbesMethod::rays_per_pass() const { return capture_texels(positions_.size(), settings_.res); }

PassStats ProbesMethod::step() {
    const Stopwatch clock;
    const uint64_t texels = capture_texels(positions_.size(), settings_.res);
    prepared_.tracer->bind();
    shading_.bind();
    surface_textures_.bind();
    positions_buffer_.bind(LF_BINDING_PROBE_POSITIONS);
    texels_.bind(LF_BINDING_PROBE_TEXELS);
    rays_.bind(LF_BINDING_PROBE_RAYS);
    ProbesParams params = this->params();
    params.texel_count = uint32_t(texels);
    capture_.use(params);
    capture_.dispatch_1d(texels);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);

    // The error estimate, as the lightmap's: the texels' RMS standard error
    // over their mean radiance, sqrt(Σ Var(mean) / n) / (Σ mean / n) (reading
    // it back also waits for the pass).
    const std::vector<glm::vec4> acc = texels_.read<glm::vec4>();
    double variance = 0.0, level = 0.0;
    for (size_t t = 0; t < texels; ++t) {
        const glm::vec4 a = acc[2 * t], b = acc[2 * t + 1];
        if (a.w < 1.0f) continue;
        const double mean = (double(a.r) + a.g + a.b) / (3.0 * a.w);
        level += mean;
        if (a.w >= 2.0f) variance += std::max(0.0, double(b.w) / a.w - mean * mean) / (a.w - 1.0);
    }
    ++stats_.pass;
    stats_.rays += rays_.read<uint32_t>()[0];  // this pass's rays (a 32-bit counter, reset every pass)
    rays_.clear_zero();
    stats_.seconds += clock.seconds();
    if (stats_.pass >= 2 && level > 0.0)
        stats_.error_estimate = std::sqrt(variance / double(texels)) / (level / double(texels));
    return stats_;
}

MethodState ProbesMethod::state() const {
    MethodState s;
    s.layout = state_layout();
    s.stats = stats_;
    s.buffers = {buffer_bytes(texels_)};
    return s;
}

void ProbesMethod::restore(const MethodState& s) {
    if (s.layout != state_layout()) throw MethodStateMismatch("the probes are placed differently");
    restore_buffers({{&texels_, "the probes' capture texels"}}, s.buffers);
    stats_ = s.stats;
}

ProbeSet ProbesMethod::probe_set(const std::vector<glm::vec4>& acc) const {
    const int r = settings_.res, m = settings_.m;
    const size_t per_probe = size_t(6) * r * r;
    ProbeSet set;
    set.m = m;
    set.capture_resolution = r;
    set.settings = description()["settings"];
    for (size_t k = 0; k < positions_.size(); ++k) {
        std::vector<glm::vec3> radiance(per_probe);
        std::vector<float> distance(per_probe);
        double rays = 0.0, backfaces = 0.0;
        float nearest = kMissDistance;
        for (size_t t = 0; t < per_probe; ++t) {
            const glm::vec4 a = acc[2 * (k * per_probe + t)], b = acc[2 * (k * per_probe + t) + 1];
            radiance[t] = a.w > 0.0f ? glm::vec3(a) / a.w : glm::vec3(0.0f);
            distance[t] = b.y > 0.0f ? b.x / b.y : kMissDistance;
            nearest = std::min(nearest, distance[t]);
            rays += a.w;
            backfaces += b.z;
        }
        Probe p;
        p.position = positions_[k];
        p.moved_from = moved_from_[k];
        p.backface_fraction = rays > 0.0 ? float(backfaces / rays) : 0.0f;
        if (p.backface_fraction > kInsideBackfaceFraction) {
            p.valid = false;
            p.why = "inside geometry";
        } else if (spacing_ > 0.0f && nearest > kFarInSpacings * spacing_) {
            p.valid = false;
            p.why = "far from every surface";
        }
        if (p.valid) {
            p.sh9 = project_cube_to_sh9(r, radiance);
            downsample_faces(r, radiance, distance, m, p.radiance, p.distance);
            const size_t corners = size_t(6) * (m + 1) * (m + 1);
            p.corner_distance.assign(corner_distances_.begin() + std::ptrdiff_t(k * corners),
                                     corner_distances_.begin() + std::ptrdiff_t((k + 1) * corners));
            const size_t centres = size_t(6) * m * m;
            p.centre_distance.assign(centre_distances_.begin() + std::ptrdiff_t(k * centres),
                                     centre_distances_.begin() + std::ptrdiff_t((k + 1) * centres));
        }
        set.probes.push_back(std::move(p));
    }
    return set;
}

SnapshotWrite ProbesMethod::snapshot(const std::filesystem::path& dir, const PassStats& stats) {
    auto acc = std::make_shared<const std::vector<glm::vec4>>(texels_.read<glm::vec4>());
    return [this, dir, acc, pass = stats.pass] {
        std::string stem = snapshot_file_name("probes", pass, "");  // "probes.pass-0004."
        stem.pop_back();
        return write_probe_set(dir, probe_set(*acc), stem);
    };
}

MethodResult ProbesMethod::finish(const std::filesystem::path& dir, const PassStats& stats) {
    const ProbeSet set = probe_set();
    MethodResult result;
    result.files = write_probe_set(dir, set);
    nlohmann::json kept = nlohmann::json::object();
    for (const Probe& p : set.probes) kept[p.why] = kept.value(p.why, 0) + 1;
    result.manifest = {
        {"settings", description()["settings"]},
        {"result", protocol::to_json(stats)},
        {"probes", set.probes.size()},
        {"kept", kept},
        {"files",
         {{"probes.json", "probe positions, validity and why, SH9 per probe, settings (gi/probes/probe_set.h)"},
          {"probes.exr",
           "every probe's M x M cube faces: R,G,B radiance and Z distance per texel, C the distance along each "
           "corner of the grid (layout in the file's lightfarm.layout)"},
          {"probes.pass-NNNN.json", "intermediate probe set"},
          {"probes.pass-NNNN.exr", "intermediate probe images"}}},
    };
    return result;
}

}  // namespace lf
