#include "bake/probe_bench.h"

#include "bake/prepared_scene.h"
#include "bake/probes_method.h"
#include "gpu/shader.h"
#include "probes/probe_eval.h"
#include "probes/probe_set.h"
#include "shaders/buffer_bindings.glsl"
#include "shaders/check_params.glsl"
#include "util/stopwatch.h"

#include <cmath>
#include <functional>
#include <random>
#include <stdexcept>
#include <string>

namespace lf {

namespace {

// Captures probes at `points` for `passes` passes, not downsampled (M = R).
ProbeSet capture(const PreparedScene& prepared, const std::vector<glm::vec3>& points, int r, int passes, uint32_t seed,
                 PassStats* stats) {
    ProbesMethod method(prepared, probes_at(points, r, r, seed));
    for (int p = 0; p < passes; ++p) *stats = method.step();
    return method.probe_set();
}

Probe downsampled(const ProbeSet& full, size_t k, int m) {
    Probe p = full.probes[k];
    downsample_faces(full.m, full.probes[k].radiance, full.probes[k].distance, m, p.radiance, p.distance);
    return p;
}

// The full-resolution texel whose centre direction is nearest `w`: its
// distance is how far the probe sees along w.
float distance_along(const ProbeSet& full, glm::vec3 w) {
    float best = -2.0f, distance = kMissDistance;
    for (int face = 0; face < 6; ++face)
        for (int j = 0; j < full.m; ++j)
            for (int i = 0; i < full.m; ++i) {
                const float c = glm::dot(cube_direction(face, (i + 0.5f) / full.m, (j + 0.5f) / full.m), w);
                if (c > best) best = c, distance = full.probes[0].distance[full.texel(face, i, j)];
            }
    return distance;
}

struct EvalPoint {
    glm::vec3 x, n;
};

// Points around the probe: through a uniformly chosen full-resolution texel,
// 5..90% of the way to the surface it sees; normals uniform on the sphere.
std::vector<EvalPoint> random_points(const ProbeSet& full, int count, uint32_t seed) {
    std::mt19937 rng(seed);
    std::uniform_int_distribution<int> face(0, 5), texel(0, full.m - 1);
    std::uniform_real_distribution<float> along(0.05f, 0.9f), sym(-1.0f, 1.0f);
    std::vector<EvalPoint> points;
    while (int(points.size()) < count) {
        const int f = face(rng), i = texel(rng), j = texel(rng);
        const float d = full.probes[0].distance[full.texel(f, i, j)];
        if (d >= kMissDistance) continue;
        glm::vec3 n;
        do n = glm::vec3(sym(rng), sym(rng), sym(rng));
        while (glm::dot(n, n) > 1.0f || glm::dot(n, n) < 1e-4f);
        const glm::vec3 w = cube_direction(f, (i + 0.5f) / full.m, (j + 0.5f) / full.m);
        points.push_back({full.probes[0].position + w * d * along(rng), glm::normalize(n)});
    }
    return points;
}

// The four of the issue, and polygon_to_point as the paper clamps it
// (ProbeEvalOptions::clip_to_horizon = false) beside lightfarm's.
const char* const kEstimators[] = {"sh9", "point_to_point", "polygon_to_point", "polygon_to_point_paper", "ddgi"};
constexpr int kEstimatorCount = 5;

// One estimator of one probe at (x, n); index into kEstimators. (ddgi with a
// single probe is its cosine-convolved radiance: the weight normalises away.)
glm::vec3 estimate(int estimator, const PreparedProbe& p, const EvalPoint& q) {
    switch (estimator) {
    case 0: return probe_sh9(p, q.n);
    case 1: return probe_point_to_point(p, q.x, q.n);
    case 2: return probe_polygon_to_point(p, q.x, q.n);
    case 3: return probe_polygon_to_point(p, q.x, q.n, false);
    default: return probe_convolved_irradiance(p, q.n);
    }
}

double channel_sum(glm::vec3 v) { return double(v.r) + v.g + v.b; }

// Σ|e − t| / Σ t over points and channels.
double normalised_error(int estimator, const PreparedProbe& p, const std::vector<EvalPoint>& points,
                        const std::vector<glm::vec3>& truth) {
    double error = 0.0, total = 0.0;
    for (size_t k = 0; k < points.size(); ++k) {
        error += channel_sum(glm::abs(estimate(estimator, p, points[k]) - truth[k]));
        total += channel_sum(truth[k]);
    }
    return total > 0.0 ? error / total : 0.0;
}

// Repeats `batch` (which evaluates `items` points) until min_seconds have
// passed; points per second.
double throughput(size_t items, double min_seconds, const std::function<void()>& batch) {
    const Stopwatch clock;
    size_t done = 0;
    do {
        batch();
        done += items;
    } while (clock.seconds() < min_seconds);
    return double(done) / clock.seconds();
}

// The GLSL include (probe_eval.glsl's lf_probe_polygon_to_point) over
// `points` points, through probe_eval_check.comp: points per second.
double gpu_polygon_throughput(const Probe& probe, int m, const std::vector<EvalPoint>& sample, double min_seconds) {
    ProbeSet one;
    one.m = m;
    one.probes = {probe};
    const size_t count = size_t(1) << 16;
    std::vector<glm::vec4> cases;
    for (size_t i = 0; i < count; ++i) {
        const EvalPoint& q = sample[i % sample.size()];
        cases.emplace_back(q.x, 0.0f);
        cases.emplace_back(q.n, 0.0f);
    }
    const ComputeProgram program("probe_eval_check.comp");
    GpuBuffer probes(pack_probe_buffer(one)), in(cases), out(count * sizeof(glm::vec4));
    CheckParams params{};
    params.item_count = uint32_t(count);
    params.mode = 1;  // one probe's polygon-to-point estimate
    params.m = m;
    params.probe = 0;
    params.probe_position_x = probe.position.x;
    params.probe_position_y = probe.position.y;
    params.probe_position_z = probe.position.z;
    program.use(params);
    probes.bind(LF_BINDING_PROBE_SET);
    in.bind(LF_BINDING_CHECK_CASES);
    out.bind(LF_BINDING_CHECK_RESULTS);
    const auto run = [&] {
        program.dispatch_1d(count);
        glFinish();
    };
    run();  // warm-up: compiles the pipeline on first use
    return throughput(count, min_seconds, run);
}

nlohmann::json throughput_rows(const ProbeSet& full, const std::vector<int>& ms, const std::vector<EvalPoint>& points,
                               double min_seconds) {
    nlohmann::json rows = nlohmann::json::array();
    for (int m : ms) {
        const Probe probe = downsampled(full, 0, m);
        const PreparedProbe prepared = prepare_probe(probe, m);
        for (int e = 0; e < kEstimatorCount; ++e) {
            volatile float sink = 0.0f;
            const double cpu = throughput(points.size(), min_seconds, [&] {
                for (const EvalPoint& q : points) sink = sink + estimate(e, prepared, q).g;
            });
            nlohmann::json row = {{"m", m}, {"estimator", kEstimators[e]}, {"cpu_points_per_second", cpu}};
            if (e == 2) row["gpu_points_per_second"] = gpu_polygon_throughput(probe, m, points, min_seconds);
            rows.push_back(row);
        }
    }
    return rows;
}

void check(const ProbeBenchOptions& o) {
    if (o.capture_resolutions.empty() || o.ms.empty() || o.random_points < 1 || o.passes < 1 || o.truth_passes < 1)
        throw std::invalid_argument("probe bench: nothing to measure");
    for (int r : o.capture_resolutions)
        for (int m : o.ms)
            if (m < 1 || r % m != 0)
                throw std::invalid_argument("probe bench: M = " + std::to_string(m) +
                                            " does not divide R = " + std::to_string(r));
}

}  // namespace

nlohmann::json run_probe_bench(const Scene& scene, const ProbeBenchOptions& o) {
    check(o);
    PreparedScene prepared;
    prepared.scene = scene;
    prepared.tracer = std::make_unique<Tracer>(prepared.scene);
    const glm::vec3 at = o.at.value_or(prepared.scene.bounds.centre());
    const glm::vec3 toward = glm::normalize(o.toward);
    PassStats stats;

    // Where the points go needs the probe's view: a first, truth-sized capture.
    const ProbeSet view = capture(prepared, {at}, o.truth_resolution, o.truth_passes, o.seed, &stats);
    if (!view.probes[0].valid) throw std::invalid_argument("probe bench: the probe is " + view.probes[0].why);
    const std::vector<EvalPoint> random = random_points(view, o.random_points, o.seed);
    const float wall = distance_along(view, toward);
    const std::vector<float> gaps{1.0f, 0.5f, 0.2f, 0.1f, 0.05f, 0.02f, 0.01f};
    std::vector<EvalPoint> sweep;
    for (float gap : gaps) sweep.push_back({at + toward * (wall * (1.0f - gap)), toward});

    // Ground truth: a probe at every point.
    std::vector<glm::vec3> truth_at;
    for (const EvalPoint& q : random) truth_at.push_back(q.x);
    for (const EvalPoint& q : sweep) truth_at.push_back(q.x);
    const ProbeSet truth_set = capture(prepared, truth_at, o.truth_resolution, o.truth_passes, o.seed + 1, &stats);
    std::vector<glm::vec3> truth_random, truth_sweep;
    for (size_t k = 0; k < truth_at.size(); ++k) {
        const EvalPoint& q = k < random.size() ? random[k] : sweep[k - random.size()];
        const glm::vec3 t = probe_convolved_irradiance(prepare_probe(truth_set.probes[k], truth_set.m), q.n);
        (k < random.size() ? truth_random : truth_sweep).push_back(t);
    }

    nlohmann::json out = {{"probe", {at.x, at.y, at.z}},
                          {"toward", {toward.x, toward.y, toward.z}},
                          {"wall", {{"distance", wall}, {"gaps", gaps}}},
                          {"truth", {{"res", o.truth_resolution}, {"passes", o.truth_passes}}},
                          {"capture", nlohmann::json::array()},
                          {"error", nlohmann::json::array()}};
    for (int r : o.capture_resolutions) {
        const ProbeSet full = capture(prepared, {at}, r, o.passes, o.seed + 2, &stats);
        out["capture"].push_back({{"res", r},
                                  {"passes", stats.pass},
                                  {"seconds", stats.seconds},
                                  {"seconds_per_pass", stats.seconds / stats.pass},
                                  {"rays", stats.rays}});
        for (int m : o.ms) {
            const PreparedProbe probe = prepare_probe(downsampled(full, 0, m), m);
            for (int e = 0; e < kEstimatorCount; ++e) {
                nlohmann::json at_wall = nlohmann::json::array();
                for (size_t k = 0; k < sweep.size(); ++k)
                    at_wall.push_back(normalised_error(e, probe, {sweep[k]}, {truth_sweep[k]}));
                out["error"].push_back({{"res", r},
                                        {"m", m},
                                        {"estimator", kEstimators[e]},
                                        {"random", normalised_error(e, probe, random, truth_random)},
                                        {"wall", at_wall}});
            }
        }
        if (r == o.capture_resolutions.front()) out["throughput"] = throughput_rows(full, o.ms, random, o.min_seconds);
    }
    return out;
}

}  // namespace lf
