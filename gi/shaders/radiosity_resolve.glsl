// Resolving a pass of the radiosity map (thesis Algorithm 4.1's update),
// texel by texel: the epoch's restart, the texel's convergence, its share of
// the pass's error estimate (resolve_texel, after each pass, inside the
// gather's dispatch), and publishing albedo x value as the reflected radiance
// that later passes' indirect rays read (publish_texel, radiosity_publish.comp,
// at the end of a cell of passes, a dispatch of its own: other texels read
// it). Neither waits at a barrier: llvmpipe runs a shader with barrier() as
// coroutines, and the gather took 25 times as long so.
#ifndef LF_RADIOSITY_RESOLVE_GLSL
#define LF_RADIOSITY_RESOLVE_GLSL
#include "buffer_bindings.glsl"
#include "lightmap_lookup.glsl"
#include "radiosity_texels.glsl"

// Variance of the mean of n samples with the given sum and sum of squares.
float variance_of_mean(float sum, float sum_sq, float n) {
    if (n < 2.0) return 0.0;
    float mean = sum / n;
    return max(0.0, (sum_sq / n - mean * mean)) / (n - 1.0);
}

// A texel's value: the direct mean plus the indirect estimate indirect rays
// read, the current epoch's once it has samples.
vec3 texel_indirect(vec4 current, vec4 previous) { return current.w > 0.0 ? current.rgb / current.w : previous.rgb; }
vec3 texel_direct(vec4 direct) { return direct.w > 0.0 ? direct.rgb / direct.w : vec3(0.0); }

// converged_error, min_samples: the program's parameter block (radiosity_params.glsl).

// After a pass: restarts the indirect estimate at an epoch's end, decides
// whether the texel has converged, and returns what it adds to the pass's
// error totals (radiosity_totals.comp sums them): the variance of its mean,
// its value, the rays it traced beyond the pass's fixed ones, and in w
// active + 2 x unknown (1 while it has not converged; 2 while its delivered
// estimate has fewer than two samples, its variance unknown). Touches texel
// i's accumulators only.
vec4 resolve_texel(uint i, bool end_epoch, float extra_rays) {
    vec4 direct = accumulators[lf_accumulator(i, LF_ACC_DIRECT)];
    vec4 moments = accumulators[lf_accumulator(i, LF_ACC_MOMENTS)];
    vec4 current = accumulators[lf_accumulator(i, LF_ACC_INDIRECT)];
    vec4 previous = accumulators[lf_accumulator(i, LF_ACC_PREVIOUS)];

    float current_var = variance_of_mean(channel_mean(current.rgb), moments.y, current.w);
    if (end_epoch && current.w > 0.0) {
        // Restart the indirect estimate from this epoch's result (see
        // RadiosityScheme). Epochs double, so it has at least the previous
        // one's samples, except in a texel that converged (stopped tracing)
        // during it: that texel keeps its previous estimate.
        if (current.w >= previous.w) {
            previous = vec4(current.rgb / current.w, current.w);
            moments.z = current_var;
        }
        current = vec4(0.0);
        moments.y = 0.0;
        accumulators[lf_accumulator(i, LF_ACC_INDIRECT)] = current;
        accumulators[lf_accumulator(i, LF_ACC_PREVIOUS)] = previous;
    }

    // The error and convergence are those of what a snapshot delivers
    // (RadiosityMapBaker::image): the indirect estimate with more samples
    // behind it, so that the reported error does not jump up when an epoch
    // restarts with few samples.
    bool deliver_current = current.w > 0.0 && current.w >= previous.w;
    vec3 delivered = texel_direct(direct) + (deliver_current ? current.rgb / current.w : previous.rgb);
    float var = variance_of_mean(channel_mean(direct.rgb), moments.x, direct.w) +
                (deliver_current ? current_var : moments.z);  // delivering current: no restart above
    float level = channel_mean(delivered);
    bool converged = converged_error > 0.0 && direct.w >= float(min_samples) && level > 0.0 &&
                     sqrt(var) < converged_error * level;
    moments.w = converged ? 1.0 : 0.0;
    accumulators[lf_accumulator(i, LF_ACC_MOMENTS)] = moments;

    bool unknown_variance = (deliver_current ? current.w : previous.w) < 2.0 || direct.w < 2.0;
    return vec4(var, level, extra_rays, (converged ? 0.0 : 1.0) + (unknown_variance ? 2.0 : 0.0));
}

// Publishes texel i's albedo x value where indirect rays read it.
void publish_texel(uint i) {
    vec4 direct = accumulators[lf_accumulator(i, LF_ACC_DIRECT)];
    vec3 indirect = texel_indirect(accumulators[lf_accumulator(i, LF_ACC_INDIRECT)], accumulators[lf_accumulator(i, LF_ACC_PREVIOUS)]);
    vec3 albedo = accumulators[lf_accumulator(i, LF_ACC_ALBEDO)].rgb;
    reflected_radiance[covered_texels[i].z] = vec4(albedo * (texel_direct(direct) + indirect), 1.0);
#ifdef LF_FINAL_GATHER
    // A final gather computes the first bounce where its ray lands: the map
    // supplies the light beyond it only (where the texel is whole).
    reflected_indirect[covered_texels[i].z] = vec4(albedo * indirect, 1.0);
#endif
}

#endif
