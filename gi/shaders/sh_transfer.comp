#version 450 core
// One pass of per-vertex SH transfer (seed §2.2, by rays instead of its
// stereographic rasterization): every receiver vertex casts samples_per_pass
// cosine-distributed rays and accumulates, per SH coefficient i,
//   shadowed (seed eq. 1.2 with L_i = y_i, cosine term max(0, n·ω)):
//     T_i = ∫ V(x,ω) max(0, n·ω) y_i(ω) dω  ≈ (1/N) Σ pi V(x,ω) y_i(ω)
//   (the cosine-weighted pdf cos/pi cancels the cosine, leaving pi·V·y_i), and
//   bounce k of interreflected transfer (Sloan, Kautz & Snyder 2002 §5):
//     T^k_i(x) = ∫ (ρ(y)/pi) T^{k-1}_i(y) max(0, n·ω) dω ≈ (1/N) Σ ρ(y) T^{k-1}_i(y)
//   with y the first surface the ray meets, T^{k-1}(y) interpolated from its
//   triangle's vertices as the previous pass resolved it.
layout(local_size_x = 64) in;  // before the includes: they use gl_WorkGroupSize

#include "buffer_bindings.glsl"
#include "sh_params.glsl"
#include "random.glsl"
#include "sampling.glsl"
#include "trace.glsl"
#include "sh_basis.glsl"

#ifndef LF_SH_BOUNCES
#define LF_SH_BOUNCES 0
#endif
#define LF_SH_BLOCKS (LF_SH_BOUNCES + 1)

// Per receiver (unique vertex or extra point, e.g. a texel sample; see
// ShTransferBaker): (position, 0), (unit normal, 0).
layout(std430, binding = LF_BINDING_SH_VERTICES) readonly buffer ShVertices { vec4 sh_vertices[]; };
// Per unique vertex: LF_SH_BLOCKS x 4 vec4 sums (T^0, T^1 …), then 4 vec4
// sums of squares of the per-ray estimate (all blocks together).
layout(std430, binding = LF_BINDING_SH_ACCUMULATORS) buffer ShAccum { vec4 sh_accum[]; };
#if LF_SH_BOUNCES > 0
// Per unique vertex: LF_SH_BLOCKS x 4 vec4, the current mean of each block.
layout(std430, binding = LF_BINDING_SH_RESOLVED) readonly buffer ShResolved { vec4 sh_resolved[]; };
// Per occluder triangle: unique vertex ids of its corners, w = 0.
layout(std430, binding = LF_BINDING_SH_TRIANGLE_IDS) readonly buffer ShTriangleIds { uvec4 sh_triangle_ids[]; };
// Per occluder triangle: albedo (RGB channel mean) at its three corners.
layout(std430, binding = LF_BINDING_SH_TRIANGLE_ALBEDO) readonly buffer ShTriangleAlbedo { vec4 sh_triangle_albedo[]; };
#endif

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= vertex_count) return;
    vec3 p = sh_vertices[2u * i].xyz;
    vec3 n = sh_vertices[2u * i + 1u].xyz;
    // Off the surface along the normal by a few ulps: a ray that leaves a
    // flat, finely tessellated surface must not hit its neighbours (the seed's
    // "blackout", its Figure 3.1).
    vec3 origin = offset_ray_origin(p, n);

    // Directions: the R2 sequence (Roberts 2018) in 0.32 fixed point, rotated
    // per vertex (Cranley-Patterson), continued across passes so every pass
    // adds points to one low-discrepancy set.
    uvec2 rotation = uvec2(pcg_hash(i ^ pcg_hash(seed)), pcg_hash(i * 7u + 1u + pcg_hash(seed + 1u)));

    vec4 sum[4 * LF_SH_BLOCKS];
    for (int k = 0; k < 4 * LF_SH_BLOCKS; ++k) sum[k] = vec4(0.0);
    vec4 squares[4] = vec4[4](vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0));

    for (uint s = 0u; s < sample_count; ++s) {
        vec3 dir = sample_cosine_hemisphere(n, r2_sample(rotation, pass * samples_per_pass + sample_first + s));
        vec3 o = origin + near_dist * dir;
        vec4 f[4] = vec4[4](vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0));
        // The transfer is one channel: light through a see-through surface
        // counts by the mean of its tint.
#if LF_SH_BOUNCES == 0
        vec3 tint = trace_transmittance(o, dir, far_dist);
        bool escaped = tint != vec3(0.0);
#else
        Hit hit = trace_closest(o, dir, far_dist);
        vec3 tint = hit.tint;
        bool escaped = hit.triangle == LF_NO_HIT;
        // Only a front face reflects what its vertices' transfer describes;
        // a back face is the inside of something (or the unknown back of a
        // double-sided sheet) and reflects nothing here.
        if (!escaped && hit.front) {
            uvec4 ids = sh_triangle_ids[hit.triangle];
            vec3 b = vec3(1.0 - hit.bary.x - hit.bary.y, hit.bary.x, hit.bary.y);
            float albedo = dot(b, sh_triangle_albedo[hit.triangle].xyz) * (tint.r + tint.g + tint.b) / 3.0;
            // Bounce k reads block k-1, which has samples from pass k-1 on:
            // starting bounce k at pass k keeps every bounce unbiased.
            for (uint k = 1u; k <= uint(LF_SH_BOUNCES) && k <= pass; ++k) {
                for (uint c = 0u; c < 4u; ++c) {
                    uint block = 4u * (k - 1u) + c;
                    uint stride = 4u * uint(LF_SH_BLOCKS);
                    vec4 t = b.x * sh_resolved[ids.x * stride + block] + b.y * sh_resolved[ids.y * stride + block] +
                             b.z * sh_resolved[ids.z * stride + block];
                    sum[4u * k + c] += albedo * t;
                    f[c] += albedo * t;
                }
            }
        }
#endif
        if (escaped) {
            vec4 y[4];
            sh_evaluate(dir, y);
            float passes = (tint.r + tint.g + tint.b) / 3.0;
            for (int c = 0; c < 4; ++c) {
                sum[c] += PI * passes * y[c];
                f[c] += PI * passes * y[c];
            }
        }
        for (int c = 0; c < 4; ++c) squares[c] += f[c] * f[c];
    }

    uint base = i * 4u * uint(LF_SH_BLOCKS + 1);
    for (int k = 0; k < 4 * LF_SH_BLOCKS; ++k) sh_accum[base + uint(k)] += sum[k];
    for (int c = 0; c < 4; ++c) sh_accum[base + 4u * uint(LF_SH_BLOCKS) + uint(c)] += squares[c];
}
