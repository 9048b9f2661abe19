#include "trace/raybench.h"

#include "gpu/shader.h"
#include "trace/tracer.h"
#include "shaders/buffer_bindings.glsl"
#include "shaders/tracer_params.glsl"
#include "util/stopwatch.h"

#include <numeric>
#include <random>

namespace lf {

namespace {

// Area-weighted random points on the scene's surfaces, with geometric normals.
std::vector<glm::vec4> surface_points(const Scene& scene, size_t count) {
    std::vector<double> cdf(scene.triangles.size());
    double total = 0.0;
    for (size_t t = 0; t < scene.triangles.size(); ++t) cdf[t] = (total += scene.triangle_area(t));
    std::vector<glm::vec4> points;
    if (total <= 0.0) return points;
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u01(0.0, 1.0);
    points.reserve(2 * count);
    for (size_t i = 0; i < count; ++i) {
        const size_t t = size_t(std::lower_bound(cdf.begin(), cdf.end(), u01(rng) * total) - cdf.begin());
        const glm::uvec3 tri = scene.triangles[std::min(t, cdf.size() - 1)];
        const float s = float(std::sqrt(u01(rng))), v = float(u01(rng));
        const glm::vec3 p = (1.0f - s) * scene.positions[tri[0]] + s * (1.0f - v) * scene.positions[tri[1]] +
                            s * v * scene.positions[tri[2]];
        // Rays leave from the side the shading normal faces (the "inside" of a room).
        glm::vec3 n = scene.geometric_normal(std::min(t, cdf.size() - 1));
        const glm::vec3 shading = scene.normals[tri[0]] + scene.normals[tri[1]] + scene.normals[tri[2]];
        if (glm::dot(n, shading) < 0.0f) n = -n;
        points.emplace_back(p, 0.0f);
        points.emplace_back(n, 0.0f);
    }
    return points;
}

}  // namespace

nlohmann::json run_raybench(const GpuContext& gpu, const Scene& scene, const RaybenchOptions& options) {
    Tracer tracer(scene);
    const BvhStats& bvh = tracer.bvh_stats();
    nlohmann::json out = {
        {"scene", scene.source},
        {"triangles", scene.triangle_count()},
        {"see_through_surfaces", tracer.has_see_through()},  // traced with the material code (Tracer::program)
        {"device", {{"vendor", gpu.info().vendor}, {"renderer", gpu.info().renderer}}},
        {"bvh",
         {{"build_seconds", bvh.build_seconds},
          {"nodes", bvh.nodes},
          {"leaves", bvh.leaves},
          {"max_depth", bvh.max_depth},
          {"bytes", bvh.bytes},
          {"sah_cost", bvh.sah_cost}}},
    };

    const std::vector<glm::vec4> points = surface_points(scene, 1u << 20);
    GpuBuffer point_buffer(points);
    GpuBuffer counts(1024 * sizeof(uint32_t));
    const ComputeProgram program = tracer.program("raybench.comp");
    tracer.bind();
    point_buffer.bind(LF_BINDING_SURFACE_POINTS);
    counts.bind(LF_BINDING_HIT_COUNTS);
    const uint32_t image_width = 2048;  // coherent rays: a 2048² image per 4M rays
    const size_t n = std::min(options.rays_per_dispatch, size_t(image_width) * image_width);
    const float diagonal = glm::length(scene.bounds.extent());
    TracerParams params{};
    params.ray_count = uint32_t(n);
    params.point_count = uint32_t(points.size() / 2);
    const glm::vec3 eye = scene.bounds.centre();
    params.eye_x = eye.x;
    params.eye_y = eye.y;
    params.eye_z = eye.z;
    params.t_far = 2.0f * diagonal + 1.0f;
    params.image_width = image_width;

    for (const char* kind : {"coherent", "incoherent"}) {
        const bool incoherent = std::string(kind) == "incoherent";
        if (incoherent && points.empty()) {
            out[kind] = nullptr;
            continue;
        }
        params.mode = incoherent ? 1u : 0u;
        params.pass = 0;
        program.use(params);
        program.dispatch_1d(n);  // warm-up: shader compile caches, first-touch of buffers
        glFinish();
        counts.clear_zero();
        // Wall time around dispatch + glFinish: timer queries are not
        // meaningful on llvmpipe, and one 4M-ray dispatch dwarfs the sync cost on a GPU.
        size_t dispatches = 0;
        double seconds = 0.0;
        while (dispatches < options.max_dispatches && seconds < options.min_seconds) {
            params.pass = uint32_t(dispatches + 1);
            program.use(params);
            const Stopwatch clock;
            program.dispatch_1d(n);
            glFinish();
            seconds += clock.seconds();
            ++dispatches;
        }
        const std::vector<uint32_t> hits = counts.read<uint32_t>();
        const double rays = double(n) * double(dispatches);
        const double hit_count = double(std::accumulate(hits.begin(), hits.end(), uint64_t(0)));
        out[kind] = {{"rays", rays},
                     {"seconds", seconds},
                     {"rays_per_second", rays / seconds},
                     {"hit_fraction", hit_count / rays}};
    }
    return out;
}

}  // namespace lf
