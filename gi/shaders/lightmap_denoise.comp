#version 450 core
// One step of the edge-avoiding à-trous wavelet filter (Dammertz, Sewtz,
// Hanika & Lensch 2010, "Edge-Avoiding À-Trous Wavelet Transform for fast
// Global Illumination Filtering"), on the lightmap atlas, with the variance
// guidance of SVGF (Schied et al. 2017, eq. 3-5). Dispatched five times with
// step = 1, 2, 4, 8, 16: a 5x5 B3-spline kernel with holes, 61x61 texels in all.
//
// A texel takes a neighbour only from its own chart (never across a seam or
// into another chart that happens to lie next to it in the atlas), and
// weighs it by how alike the two are:
//   normal     max(0, n_p . n_q)^64
//   plane      exp(-|n_p . (x_q - x_p)| / s_p)        s_p: the texel's world size
//   luminance  exp(-|l_p - l_q| / (4 sigma_p + eps))  sigma_p: the texel's standard error
// so flat, alike, noisy texels average and edges the noise cannot explain
// (a shadow's border, where the error is small against the step) stay.
layout(local_size_x = 64) in;
#include "buffer_bindings.glsl"

// Per atlas texel: (position, chart as uint bits; 0xffffffff = no texel), (normal, world size).
layout(std430, binding = LF_BINDING_DENOISE_GUIDE) readonly buffer Guide { vec4 guide[]; };
// Per atlas texel: (rgb, variance of the luminance estimate).
layout(std430, binding = LF_BINDING_DENOISE_IN) readonly buffer ColourIn { vec4 colour_in[]; };
layout(std430, binding = LF_BINDING_DENOISE_OUT) writeonly buffer ColourOut { vec4 colour_out[]; };

uniform uint width;
uniform uint height;
uniform int step_size;

const uint NO_TEXEL = 0xffffffffu;
const float KERNEL[3] = float[](3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0);

float luminance(vec3 c) { return dot(c, vec3(0.2126, 0.7152, 0.0722)); }

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= width * height) return;
    vec4 centre = colour_in[i];
    uint chart = floatBitsToUint(guide[2u * i].w);
    if (chart == NO_TEXEL) {
        colour_out[i] = centre;
        return;
    }
    vec3 x_p = guide[2u * i].xyz;
    vec3 n_p = guide[2u * i + 1u].xyz;
    float s_p = max(guide[2u * i + 1u].w, 1e-6);
    float l_p = luminance(centre.rgb);
    float sigma_p = sqrt(max(centre.w, 0.0));
    ivec2 p = ivec2(i % width, i / width);

    vec3 sum = vec3(0.0);
    float weights = 0.0, variance = 0.0;
    for (int dy = -2; dy <= 2; ++dy) {
        for (int dx = -2; dx <= 2; ++dx) {
            ivec2 q = p + ivec2(dx, dy) * step_size;
            if (q.x < 0 || q.y < 0 || q.x >= int(width) || q.y >= int(height)) continue;
            uint j = uint(q.y) * width + uint(q.x);
            if (floatBitsToUint(guide[2u * j].w) != chart) continue;
            vec4 c = colour_in[j];
            vec3 n_q = guide[2u * j + 1u].xyz;
            float w = KERNEL[abs(dx)] * KERNEL[abs(dy)];
            if (j != i) {  // the centre weighs in whole (even with a degenerate normal)
                w *= pow(max(0.0, dot(n_p, n_q)), 64.0);
                w *= exp(-abs(dot(n_p, guide[2u * j].xyz - x_p)) / s_p);
                w *= exp(-abs(luminance(c.rgb) - l_p) / (4.0 * sigma_p + 1e-6));
            }
            sum += w * c.rgb;
            weights += w;
            variance += w * w * c.w;
        }
    }
    // The centre always weighs in, so weights > 0.
    colour_out[i] = vec4(sum / weights, variance / (weights * weights));
}
