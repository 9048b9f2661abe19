#version 450 core
// After a dispatch of the gather: sums its passes' texel totals
// (resolve_texel) per work group, one slot of partial sums per pass, which
// RadiosityMapBaker reads back once per batch (totals_of). Its own small
// dispatch: a reduction waits at barriers, which the gather must not
// (radiosity_resolve.glsl).
layout(local_size_x = 64) in;  // before the includes: they use gl_WorkGroupSize

#include "buffer_bindings.glsl"
#include "radiosity_params.glsl"
#include "radiosity_texels.glsl"

layout(std430, binding = LF_BINDING_TEXEL_TOTALS) readonly buffer TexelTotals { vec4 texel_totals[]; };
// Per pass, from k x partials_stride, per work group two vec4: (sum of the
// variance of the mean, sum of the value, active texels, covered texels),
// (extra rays traced, texels whose delivered estimate has fewer than two
// samples (its variance unknown), 0, 0).
layout(std430, binding = LF_BINDING_ERROR_PARTIALS) writeonly buffer ErrorPartials { vec4 error_partials[]; };

shared vec4 partial[64];
shared vec2 partial_rays[64];

void main() {
    uint i = covered_index();
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    for (uint k = 0u; k < pass_count; ++k) {
        vec4 t = i < covered_count ? texel_totals[k * covered_count + i] : vec4(0.0);
        float is_active = mod(t.w, 2.0), unknown = floor(t.w * 0.5);  // resolve_texel's w
        partial[gl_LocalInvocationIndex] = vec4(t.xy, is_active, i < covered_count ? 1.0 : 0.0);
        partial_rays[gl_LocalInvocationIndex] = vec2(t.z, unknown);
        barrier();
        for (uint stride = 32u; stride > 0u; stride >>= 1u) {
            if (gl_LocalInvocationIndex < stride) {
                partial[gl_LocalInvocationIndex] += partial[gl_LocalInvocationIndex + stride];
                partial_rays[gl_LocalInvocationIndex] += partial_rays[gl_LocalInvocationIndex + stride];
            }
            barrier();
        }
        if (gl_LocalInvocationIndex == 0u) {
            error_partials[k * partials_stride + 2u * group] = partial[0];
            error_partials[k * partials_stride + 2u * group + 1u] = vec4(partial_rays[0], 0.0, 0.0);
        }
        barrier();  // the next pass's sums overwrite what this one's first invocation read
    }
}
