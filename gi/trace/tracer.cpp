#include "trace/tracer.h"

#include "gpu/context.h"
#include "shaders/buffer_bindings.glsl"
#include "shaders/tracer_params.glsl"

namespace lf {

Tracer::Tracer(const Bvh& bvh, const Scene& scene)
    : stats_(bvh.stats), see_through_(scene, SurfaceTextures::Which::SeeThrough) {
    nodes_ = GpuBuffer(bvh.nodes);
    // A see-through triangle is marked in its record: the traversal passes
    // over it and trace.glsl's walk decides what it does to the light.
    std::vector<BvhTriangle> triangles = bvh.triangles;
    for (BvhTriangle& t : triangles) {
        const bool see_through = scene.materials[scene.triangle_material.at(t.scene_triangle)].is_see_through();
        t.pad1 = uint_bits(see_through ? 1u : 0u);
        has_see_through_ = has_see_through_ || see_through;
    }
    triangles_ = GpuBuffer(triangles);
}

void Tracer::rewind(const Scene& scene) {
    std::vector<BvhTriangle> triangles = triangles_.read<BvhTriangle>();
    for (BvhTriangle& t : triangles) {
        const glm::uvec3 tri = scene.triangles.at(t.scene_triangle);
        t.v0 = scene.positions[tri[0]];
        t.v1 = scene.positions[tri[1]];
        t.v2 = scene.positions[tri[2]];
    }
    triangles_.upload(triangles.data(), triangles.size() * sizeof(BvhTriangle));
}

void Tracer::bind() const {
    nodes_.bind(LF_BINDING_BVH_NODES);
    triangles_.bind(LF_BINDING_BVH_TRIANGLES);
    see_through_.bind();
}

ComputeProgram Tracer::program(const std::string& name, ShaderDefines defines) const {
    defines.emplace_back("LF_SEE_THROUGH", has_see_through_ ? "1" : "0");
    return ComputeProgram(name, defines);
}

GpuBuffer Tracer::trace_rays(const std::vector<Ray>& rays, uint32_t mode) const {
    static_assert(sizeof(Ray) == 32 && sizeof(RayHit) == sizeof(glm::vec4));
    if (!trace_program_) trace_program_ = std::make_unique<ComputeProgram>(program("trace_rays.comp"));
    GpuBuffer ray_buffer(rays);
    GpuBuffer hit_buffer(rays.size() * sizeof(glm::vec4));
    bind();
    ray_buffer.bind(LF_BINDING_RAYS);
    hit_buffer.bind(LF_BINDING_HITS);
    TracerParams params{};
    params.ray_count = uint32_t(rays.size());
    params.mode = mode;
    trace_program_->use(params);
    trace_program_->dispatch_1d(rays.size());
    return hit_buffer;
}

std::vector<RayHit> Tracer::trace(const std::vector<Ray>& rays) const {
    if (rays.empty()) return {};
    return trace_rays(rays, 0).read<RayHit>();
}

std::vector<glm::vec3> Tracer::transmittance(const std::vector<Ray>& rays) const {
    if (rays.empty()) return {};
    const std::vector<glm::vec4> out = trace_rays(rays, 1).read<glm::vec4>();
    return std::vector<glm::vec3>(out.begin(), out.end());
}

}  // namespace lf
