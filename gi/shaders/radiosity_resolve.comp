#version 450 core
// After each pass: turn the accumulators into the lightmap value of every
// covered texel, publish albedo x value as the reflected radiance that the
// next pass's indirect rays read, and estimate the error.
layout(local_size_x = 64) in;  // before the includes: they use gl_WorkGroupSize

#include "buffer_bindings.glsl"
#include "lightmap_lookup.glsl"
#include "radiosity_texels.glsl"


// Per workgroup, two vec4: (sum of the variance of the mean, sum of the value,
// active texels, covered texels), (extra rays traced this pass, texels whose
// delivered estimate has fewer than two samples (its variance unknown), 0, 0).
layout(std430, binding = LF_BINDING_ERROR_PARTIALS) writeonly buffer ErrorPartials { vec4 error_partials[]; };

uniform uint end_epoch;        // 1 after the last pass of an epoch: the current indirect estimate becomes "previous"
uniform float converged_error; // > 0: texels whose relative standard error is below this stop tracing
uniform uint min_samples;      // before which no texel is called converged

shared vec4 partial[64];
shared vec2 partial_rays[64];  // extra rays, texels of unknown variance

// Variance of the mean of n samples with the given sum and sum of squares.
float variance_of_mean(float sum, float sum_sq, float n) {
    if (n < 2.0) return 0.0;
    float mean = sum / n;
    return max(0.0, (sum_sq / n - mean * mean)) / (n - 1.0);
}

void main() {
    uint i = covered_index();
    vec4 contribution = vec4(0.0);
    float extra_rays = 0.0, unknown_variance = 0.0;
    if (i < covered_count) {
        vec4 direct = accumulators[5u * i];
        vec4 moments = accumulators[5u * i + 1u];
        vec4 current = accumulators[5u * i + 2u];
        vec4 previous = accumulators[5u * i + 3u];
        vec4 albedo_and_rays = accumulators[5u * i + 4u];
        vec3 albedo = albedo_and_rays.rgb;
        extra_rays = albedo_and_rays.w;
        accumulators[5u * i + 4u].w = 0.0;

        float current_var = variance_of_mean(channel_mean(current.rgb), moments.y, current.w);
        if (end_epoch != 0u && current.w > 0.0) {
            // Restart the indirect estimate from this epoch's result (see
            // RadiosityScheme). Epochs double, so it has at least the previous
            // one's samples, except in a texel that converged (stopped
            // tracing) during it: that texel keeps its previous estimate.
            if (current.w >= previous.w) {
                previous = vec4(current.rgb / current.w, current.w);
                moments.z = current_var;
            }
            current = vec4(0.0);
            moments.y = 0.0;
            accumulators[5u * i + 2u] = current;
            accumulators[5u * i + 3u] = previous;
        }
        vec3 direct_mean = direct.w > 0.0 ? direct.rgb / direct.w : vec3(0.0);
        // Indirect rays read the current epoch's estimate once it has samples.
        bool use_current = current.w > 0.0;
        vec3 indirect = use_current ? current.rgb / current.w : previous.rgb;
        vec3 value = direct_mean + indirect;
        reflected_radiance[covered_texels[i].z] = vec4(albedo * value, 1.0);
#ifdef LF_FINAL_GATHER
        // A final gather computes the first bounce where its ray lands: the
        // map supplies the light beyond it only (where the texel is whole).
        reflected_indirect[covered_texels[i].z] = vec4(albedo * indirect, 1.0);
#endif

        // The error and convergence are those of what a snapshot delivers
        // (RadiosityMapBaker::image): the indirect estimate with more samples
        // behind it, so that the reported error does not jump up when an
        // epoch restarts with few samples.
        bool deliver_current = current.w > 0.0 && current.w >= previous.w;
        vec3 delivered = direct_mean + (deliver_current ? current.rgb / current.w : previous.rgb);
        float var = variance_of_mean(channel_mean(direct.rgb), moments.x, direct.w) +
                    (deliver_current ? variance_of_mean(channel_mean(current.rgb), moments.y, current.w) : moments.z);
        float level = channel_mean(delivered);
        unknown_variance = (deliver_current ? current.w : previous.w) < 2.0 || direct.w < 2.0 ? 1.0 : 0.0;
        bool converged = converged_error > 0.0 && direct.w >= float(min_samples) && level > 0.0 &&
                         sqrt(var) < converged_error * level;
        moments.w = converged ? 1.0 : 0.0;
        accumulators[5u * i + 1u] = moments;
        contribution = vec4(var, level, converged ? 0.0 : 1.0, 1.0);
    }
    partial[gl_LocalInvocationIndex] = contribution;
    partial_rays[gl_LocalInvocationIndex] = vec2(extra_rays, unknown_variance);
    barrier();
    for (uint stride = 32u; stride > 0u; stride >>= 1u) {
        if (gl_LocalInvocationIndex < stride) {
            partial[gl_LocalInvocationIndex] += partial[gl_LocalInvocationIndex + stride];
            partial_rays[gl_LocalInvocationIndex] += partial_rays[gl_LocalInvocationIndex + stride];
        }
        barrier();
    }
    uint group = gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
    if (gl_LocalInvocationIndex == 0u) {
        error_partials[2u * group] = partial[0];
        error_partials[2u * group + 1u] = vec4(partial_rays[0], 0.0, 0.0);
    }
}
