// SH transfer (Staniszewski 2005, "Calculating diffuse SH coefficients on
// GPU"): for every vertex, visibility x clamped cosine projected on the 16 SH
// basis functions, so a renderer shades it under any environment with a dot
// product E = Σ T_i L_i. The seed rasterizes a stereographic view from each
// vertex (§2.2.2); this traces cosine-distributed rays with the project's one
// tracer, pass by pass (one ProgressiveMethod step each), and adds interreflection bounces
// (Sloan, Kautz & Snyder 2002) on request.
#pragma once

#include "bake/method_state.h"
#include "bake/progressive.h"
#include "gpu/shader.h"
#include "shaders/sh_params.glsl"
#include "scene/scene.h"
#include "sh/sh_basis.h"
#include "trace/tracer.h"

#include <memory>
#include <vector>

namespace lf {

struct ShTransferSettings {
    int samples_per_pass = 64;  // rays per vertex per pass
    int bounces = 0;            // interreflection bounces (0 = shadowed transfer only), at most kMaxBounces
    uint32_t seed = 1;
    // The seed's §3.1 clip planes, off by default: occluders nearer than
    // `near` or further than `far` (metres; 0 = no limit) are ignored.
    float near = 0.0f;
    float far = 0.0f;
    // The seed's §3.1 occluder/receiver sets, as glTF mesh indices. Empty =
    // every mesh. A vertex of a mesh that is not a receiver is not traced: it
    // gets the unoccluded transfer of its normal (lit, never shadowed).
    std::vector<int> occluder_meshes;
    std::vector<int> receiver_meshes;

    static constexpr int kMaxBounces = 4;
};

// A receiver that is not a Scene vertex: a lightmap texel's sample point
// (--sh-per-texel). It is traced exactly as a receiver vertex is: same
// directions, same occluders, same bounces (which read the vertices' transfer
// where a ray lands).
struct ShReceiverPoint {
    glm::vec3 position;
    glm::vec3 normal;  // unit
};

// Transfer per Scene vertex (16 coefficients each, index l(l+1)+m), with the
// standard error of each coefficient's estimate, and the same for every extra
// receiver point given to the baker, in its order.
struct ShVertexTransfer {
    std::vector<ShCoefficients> coefficients;
    std::vector<ShCoefficients> standard_error;
    std::vector<bool> traced;  // false: not a receiver (unoccluded transfer)
    std::vector<ShCoefficients> point_coefficients;
    std::vector<ShCoefficients> point_standard_error;
};

class ShTransferBaker {
public:
    // `tracer` is the whole scene's BVH (shared by a bake's methods). With
    // occluder_meshes set, the baker builds its own BVH of those meshes instead.
    // `points`: extra receivers beyond the scene's vertices (texel samples);
    // every one is traced (the caller applies receiver_meshes to them).
    ShTransferBaker(const Scene& scene, const Tracer& tracer, const ShTransferSettings& settings,
                    const std::vector<ShReceiverPoint>& points = {});
    ~ShTransferBaker();

    // One pass: samples_per_pass rays per unique receiver vertex and per
    // extra receiver point. The error estimate is the relative standard
    // error of the transfer vectors, v over every traced receiver (vertices
    // and points): sqrt(Σ_v Σ_i Var(T_vi) / Σ_v Σ_i T_vi²) (iid variance: an
    // upper bound for the stratified directions used).
    PassStats step();

    ShVertexTransfer snapshot() const;

    size_t unique_vertices() const { return unique_count_ - point_count_; }
    size_t receiver_vertices() const { return receiver_vertex_count_; }
    uint64_t rays_per_pass() const { return uint64_t(receiver_count_) * uint64_t(settings_.samples_per_pass); }
    size_t receiver_points() const { return point_count_; }
    // Resuming (bake/method_state.h): the running sums and their resolved means.
    MethodState state() const;
    void restore(const MethodState& state);

    uint64_t samples_per_vertex() const { return uint64_t(stats_.pass) * uint64_t(settings_.samples_per_pass); }

private:
    void build_receivers(const Scene& scene, const std::vector<ShReceiverPoint>& points);
    void build_occluders(const Scene& scene);
    uint64_t layout() const;  // which vertex or point each receiver entry is

    const Scene& scene_;
    ShTransferSettings settings_;
    std::unique_ptr<Tracer> own_tracer_;  // occluder subset only
    const Tracer* tracer_ = nullptr;

    // Every receiver, one list, one path through the shaders: unique receiver
    // vertices [0, receiver_vertex_count_), then the extra points
    // [receiver_vertex_count_, receiver_count_), which together are the traced
    // range, then the unique vertices that do not receive [receiver_count_, unique_count_).
    // Scene vertex -> its unique entry.
    std::vector<uint32_t> unique_of_vertex_;
    std::vector<glm::vec3> unique_normal_;
    size_t unique_count_ = 0, receiver_count_ = 0, receiver_vertex_count_ = 0, point_count_ = 0;

    ComputeProgram transfer_;
    ComputeProgram resolve_;
    GpuBuffer vertices_, accum_, resolved_, triangle_ids_, triangle_albedo_, error_partials_;
    PassStats stats_;
    bool software_renderer_ = false;  // Mesa llvmpipe: passes run in slices
};

}  // namespace lf
