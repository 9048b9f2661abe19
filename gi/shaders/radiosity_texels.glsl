// The per-texel state of a radiosity-map bake, shared by its passes.
#ifndef LF_RADIOSITY_TEXELS_GLSL
#define LF_RADIOSITY_TEXELS_GLSL
#include "buffer_bindings.glsl"
#include "unit_vector.glsl"

// Sample points inside texel footprints, two vec4 (32 bytes) each, so that
// the 47 M points of the staircase's 4096² atlas fit one buffer
// (kMaxGpuBufferBytes; at 48 bytes they did not):
//   [2s]      position, world texel size
//   [2s + 1]  geometric normal on the shading normal's side (xyz), shading
//             normal packed in w (lf_unpack_unit_vector)
// Read through the sample_* functions below.
#ifndef LF_SAMPLE_POINTS_ACCESS
#define LF_SAMPLE_POINTS_ACCESS readonly
#endif
layout(std430, binding = LF_BINDING_TEXEL_SAMPLE_POINTS) LF_SAMPLE_POINTS_ACCESS buffer TexelSamplePoints { vec4 sample_points[]; };
#ifdef LF_MOVED_SAMPLES
// One bit per sample point, set where texel_relocate.comp moved it out of
// geometry (texel_anchor.comp marks its texel; the bake counts them).
layout(std430, binding = LF_BINDING_MOVED_SAMPLES) buffer MovedSamples { uint moved_samples[]; };
bool sample_was_moved(uint s) { return (moved_samples[s / 32u] & (1u << (s % 32u))) != 0u; }
#endif
// Per covered texel: (first sample point, sample count, atlas index, 0).
layout(std430, binding = LF_BINDING_COVERED_TEXELS) readonly buffer CoveredTexels { uvec4 covered_texels[]; };

// Per covered texel, LF_TEXEL_ACCUMULATORS (5) vec4 of running sums (thesis
// Algorithm 4.1's accumulators Eu_e, Eu_i, with second moments for the
// error estimate), at the offsets buffer_bindings.glsl names:
//   LF_ACC_DIRECT:   sum of E/pi samples (rgb), sample count
//   LF_ACC_MOMENTS:  second moments (of the channel mean): direct, current indirect; previous epoch's variance of the mean; active flag
//   LF_ACC_INDIRECT: indirect, current epoch: sum (rgb), sample count
//   LF_ACC_PREVIOUS: indirect, previous epoch: mean (rgb), sample count
//   LF_ACC_ALBEDO:   albedo (rgb), passes whose sample found any light (direct or indirect > 0)
layout(std430, binding = LF_BINDING_TEXEL_ACCUMULATORS) buffer TexelAccumulators { vec4 accumulators[]; };
// Where covered texel i's `field` (LF_ACC_…) is in `accumulators`.
uint lf_accumulator(uint i, uint field) { return LF_TEXEL_ACCUMULATORS * i + field; }

// covered_count: the program's parameter block (radiosity_params.glsl).

uint covered_index() {
    return gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
}

float channel_mean(vec3 c) { return (c.r + c.g + c.b) * (1.0 / 3.0); }

vec3 sample_position(uint s) { return sample_points[2u * s].xyz; }
float sample_texel_size(uint s) { return sample_points[2u * s].w; }
vec3 sample_geometric_normal(uint s) { return sample_points[2u * s + 1u].xyz; }
vec3 sample_normal(uint s) { return lf_unpack_unit_vector(sample_points[2u * s + 1u].w); }

#endif
