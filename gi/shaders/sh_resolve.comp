#version 450 core
// After each transfer pass: the mean of every block (T^0, T^1 …) for the next
// pass's bounces and the snapshot, and per work group the totals of the error
// estimate: Σ over coefficients of the variance of the mean, and Σ T_i².
layout(local_size_x = 64) in;
#include "buffer_bindings.glsl"
#include "sh_params.glsl"

#ifndef LF_SH_BOUNCES
#define LF_SH_BOUNCES 0
#endif
#define LF_SH_BLOCKS (LF_SH_BOUNCES + 1)

layout(std430, binding = LF_BINDING_SH_ACCUMULATORS) readonly buffer ShAccum { vec4 sh_accum[]; };
layout(std430, binding = LF_BINDING_SH_RESOLVED) writeonly buffer ShResolved { vec4 sh_resolved[]; };
layout(std430, binding = LF_BINDING_SH_ERROR_PARTIALS) writeonly buffer ShErrorPartials { vec4 sh_error_partials[]; };

// Rays behind block k after `pass` passes: bounce k started at pass k.
float block_samples(int k) { return float(max(int(pass) - k, 0)) * float(samples_per_pass); }

shared vec2 partial[64];

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    vec2 mine = vec2(0.0);
    if (i < vertex_count) {
        uint base = i * 4u * uint(LF_SH_BLOCKS + 1);
        vec4 total[4] = vec4[4](vec4(0.0), vec4(0.0), vec4(0.0), vec4(0.0));
        for (int k = 0; k < LF_SH_BLOCKS; ++k) {
            float count = block_samples(k);
            for (int c = 0; c < 4; ++c) {
                vec4 mean = count > 0.0 ? sh_accum[base + uint(4 * k + c)] / count : vec4(0.0);
                sh_resolved[i * 4u * uint(LF_SH_BLOCKS) + uint(4 * k + c)] = mean;
                total[c] += mean;
            }
        }
        // Variance of the mean of the per-ray estimate (all blocks summed per
        // ray), from its second moment: iid-sample variance, an upper bound
        // for the stratified directions actually used.
        float n = block_samples(0);
        if (n > 1.0) {
            for (int c = 0; c < 4; ++c) {
                vec4 second = sh_accum[base + 4u * uint(LF_SH_BLOCKS) + uint(c)] / n;
                vec4 var = max(second - total[c] * total[c], vec4(0.0)) / (n - 1.0);
                mine.x += var.x + var.y + var.z + var.w;
                mine.y += dot(total[c], total[c]);
            }
        }
    }
    partial[gl_LocalInvocationID.x] = mine;
    barrier();
    if (gl_LocalInvocationID.x == 0u) {
        vec2 s = vec2(0.0);
        for (int k = 0; k < 64; ++k) s += partial[k];
        sh_error_partials[gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x] = vec4(s, 0.0, 0.0);
    }
}
