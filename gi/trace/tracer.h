// The one ray tracer: the scene's BVH on the GPU.
//
// Two ways to use it:
//  * from a method's own compute shader, which includes trace.glsl and calls
//    trace_closest / trace_occluded / trace_transmittance after
//    Tracer::bind(). This is how the bake
//    methods use it: a ray is generated, traced and shaded in one invocation,
//    so rays and hits never travel through memory (32-48 bytes per ray each
//    way would cost more bandwidth than the traversal itself on small scenes).
//  * batched, Tracer::trace(rays): rays from the CPU, hits back. For tests,
//    tools, and the rare caller whose rays come from the CPU.
// Light passes through see-through surfaces (alpha cut-outs, blending,
// transmission: Material::is_see_through) as trace.glsl says; the batched
// queries and the texel placement checks see the geometry alone.
#pragma once

#include "gpu/shader.h"
#include "scene/scene.h"
#include "trace/bvh.h"
#include "trace/surface_textures.h"

#include <glm/glm.hpp>

#include <memory>
#include <vector>

namespace lf {

struct Ray {
    glm::vec3 origin;
    float t_max;
    glm::vec3 direction;
    uint32_t any_hit = 0;  // 1: occlusion query, stop at the first hit
};

constexpr uint32_t kNoHit = 0xffffffffu;

struct RayHit {
    float t = 0.0f;
    uint32_t triangle = kNoHit;  // scene triangle index
    glm::vec2 bary{0.0f};        // weights of the triangle's 2nd and 3rd vertex
};

class Tracer {
public:
    explicit Tracer(const Scene& scene) : Tracer(build_bvh(scene), scene) {}
    // A tree built elsewhere from `scene` (build_bvh runs on any thread; this uploads it).
    Tracer(const Bvh& bvh, const Scene& scene);
    // Binds the BVH at LF_BINDING_BVH_NODES and LF_BINDING_BVH_TRIANGLES, and
    // the see-through surfaces' materials (shaders/buffer_bindings.glsl).
    void bind() const;
    std::vector<RayHit> trace(const std::vector<Ray>& rays) const;
    // The share of light that passes along each ray (0 < t < t_max), per
    // channel: 0 past an opaque surface, see-through ones passing their
    // transmittance (cut-outs, blends, glass). `any_hit` is not read.
    std::vector<glm::vec3> transmittance(const std::vector<Ray>& rays) const;
    // Takes the winding of `scene`'s triangles: the scene this tracer was
    // built from with some triangles turned round (the same triangles in the
    // same order at the same positions; its vertices may be split). The tree
    // is unchanged, as turning a triangle moves none of its points, so this
    // is a re-upload of the triangles, not a rebuild (0.24 s of the
    // staircase's preparation on 2 cores).
    void rewind(const Scene& scene);
    const BvhStats& bvh_stats() const { return stats_; }
    // A program that includes trace.glsl, built for this scene: `defines`
    // plus LF_SEE_THROUGH, 1 where a triangle is see-through and 0 where
    // none is: a scene with no use for the see-through code (the leaf
    // loop's test of the mark, the walk of the surfaces after the
    // traversal) is traced without it. While the material code sat in the
    // leaf loop it cost llvmpipe 4x (docs/BENCHMARKS.md); now the walk costs
    // ~1.3x on grey_white_room. trace.glsl stops the compile of a program
    // built any other way.
    ComputeProgram program(const std::string& name, ShaderDefines defines = {}) const;
    bool has_see_through() const { return has_see_through_; }

private:
    // trace_rays.comp in `mode` over `rays` (not empty): its output, 16 bytes per ray.
    GpuBuffer trace_rays(const std::vector<Ray>& rays, uint32_t mode) const;

    BvhStats stats_;
    bool has_see_through_ = false;
    GpuBuffer nodes_;
    GpuBuffer triangles_;
    SurfaceTextures see_through_;                            // Which::SeeThrough
    mutable std::unique_ptr<ComputeProgram> trace_program_;  // built on first use
};

}  // namespace lf
