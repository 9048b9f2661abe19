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
//   luminance  exp(-(l_p - l_q)^2 / (2 k^2 (sigma_p^2 + v_q)))   k = 2
// with sigma_p the standard error around the texel and v_q the tap's
// variance, so flat, alike, noisy texels average and edges the noise cannot
// explain (a shadow's border, where the error is small against the step)
// stay. The luminance weight asks whether the two differ by more than their
// noise: a difference of two estimates has the sum of their variances, and
// a Gaussian's tail (issue #53): a thin sunlit line 8 standard errors above
// the floor beside it lends each floor tap e^-8 of its weight, where the
// Laplacian exp(-|l_p - l_q| / 4 sigma_p) of SVGF lent e^-2 (and more:
// sigma_p, the neighbourhood's, grows beside the line with the line's own
// noise), and the texels three either side of a 3 cm line came out +11% to
// +19% too bright.
//
// Each step fits a plane (value = a + b dx + c dy over the atlas offsets)
// to its weighted taps and keeps a, rather than their weighted mean: the two
// agree where the taps lie symmetrically around the texel, but where a
// chart's border cuts the kernel off on one side, the mean would pull a
// texel at the end of a gradient (a wall towards a corner) towards the
// chart's inside, and the fit does not (a local linear regression, as in
// Moon et al. 2014's weighted local regression for denoising).
layout(local_size_x = 64) in;
#include "buffer_bindings.glsl"
#include "denoise_params.glsl"

// Per atlas texel: (position, chart as uint bits; 0xffffffff = no texel), (normal, world size).
layout(std430, binding = LF_BINDING_DENOISE_GUIDE) readonly buffer Guide { vec4 guide[]; };
// Per atlas texel: (rgb, variance of the luminance estimate).
layout(std430, binding = LF_BINDING_DENOISE_IN) readonly buffer ColourIn { vec4 colour_in[]; };
layout(std430, binding = LF_BINDING_DENOISE_OUT) writeonly buffer ColourOut { vec4 colour_out[]; };
// Per atlas texel: 1 where the edge-aware steps are to keep the texel as it
// is (a 0 the bake is sure of: LightmapDenoiser's sure_darks), else 0.
layout(std430, binding = LF_BINDING_DENOISE_KEEP) readonly buffer Keep { uint keep[]; };

const uint NO_TEXEL = 0xffffffffu;
const float KERNEL[3] = float[](3.0 / 8.0, 1.0 / 4.0, 1.0 / 16.0);

float luminance(vec3 c) { return dot(c, vec3(0.2126, 0.7152, 0.0722)); }

struct Texel {
    vec3 position;
    vec3 normal;
    float size;     // world size
    float luminance;
    float sigma;    // standard error of the luminance
    uint chart;
};

// The variance of texel p's luminance, 3x3-Gaussian-filtered over its own
// chart's adjacent texels (SVGF, Schied et al. 2017, §4.3). A texel's own
// variance estimate rises with its own error: a texel that found the light
// in a few of its paths is both bright and uncertain, one that did not is
// both a little dark and sure, so weighing neighbours by the centre's own
// sigma pulled the bright ones in and kept the dark ones apart, and the mean
// went dark (docs/BENCHMARKS.md, "Denoising"). The neighbourhood's variance
// treats both alike.
float filtered_variance(ivec2 p, uint chart) {
    const float gauss[2] = float[](0.25, 0.125);
    float sum = 0.0, weights = 0.0;
    for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
            ivec2 q = p + ivec2(dx, dy);
            if (q.x < 0 || q.y < 0 || q.x >= int(width) || q.y >= int(height)) continue;
            uint j = uint(q.y) * width + uint(q.x);
            if (floatBitsToUint(guide[2u * j].w) != chart) continue;
            float w = gauss[abs(dx)] * gauss[abs(dy)];
            sum += w * max(colour_in[j].w, 0.0);
            weights += w;
        }
    return sum / weights;  // the centre is always in its own chart
}

Texel texel_at(uint i) {
    Texel t;
    t.position = guide[2u * i].xyz;
    t.chart = floatBitsToUint(guide[2u * i].w);
    t.normal = guide[2u * i + 1u].xyz;
    t.size = max(guide[2u * i + 1u].w, 1e-6);
    t.luminance = luminance(colour_in[i].rgb);
    t.sigma = t.chart == NO_TEXEL || luminance_weights == 0u
                  ? 0.0
                  : sqrt(filtered_variance(ivec2(i % width, i / width), t.chart));
    return t;
}

// The weight of tap (dx, dy) for texel p, and its index; 0 where it is off
// the atlas or in another chart. `where` is its part from the guide alone
// (kernel, chart, normal, plane): whether the tap is there to fit with.
float tap_weight(ivec2 p, const Texel centre, int dx, int dy, out uint j, out float where) {
    ivec2 q = p + ivec2(dx, dy) * step_size;
    j = 0u;
    where = 0.0;
    if (q.x < 0 || q.y < 0 || q.x >= int(width) || q.y >= int(height)) return 0.0;
    j = uint(q.y) * width + uint(q.x);
    if (floatBitsToUint(guide[2u * j].w) != centre.chart) return 0.0;
    float w = KERNEL[abs(dx)] * KERNEL[abs(dy)];
    where = w;
    if (dx == 0 && dy == 0) return w;  // the centre weighs in whole (even with a degenerate normal)
    w *= pow(max(0.0, dot(centre.normal, guide[2u * j + 1u].xyz)), 64.0);
    w *= exp(-abs(dot(centre.normal, guide[2u * j].xyz - centre.position)) / centre.size);
    where = w;
    if (luminance_weights != 0u) {
        float d = luminance(colour_in[j].rgb) - centre.luminance;
        float pair = centre.sigma * centre.sigma + max(colour_in[j].w, 0.0);
        w *= exp(-d * d / (2.0 * 4.0 * pair + 1e-12));
    }
    return w;
}

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= width * height) return;
    Texel centre = texel_at(i);
    if (centre.chart == NO_TEXEL || (luminance_weights != 0u && keep[i] != 0u)) {
        colour_out[i] = colour_in[i];
        return;
    }
    ivec2 p = ivec2(i % width, i / width);

    // The taps' weights (read once: the fit and the sum both need them), and
    // the normal equations of the weighted fit: M = sum of w f f^T, f = (1, dx, dy).
    float w[25];
    uint tap[25];
    mat3 m = mat3(0.0), m_where = mat3(0.0);
    for (int t = 0; t < 25; ++t) {
        int dx = t % 5 - 2, dy = t / 5 - 2;
        float where;
        w[t] = tap_weight(p, centre, dx, dy, tap[t], where);
        vec3 f = vec3(1.0, dx, dy);
        m += w[t] * outerProduct(f, f);
        m_where += where * outerProduct(f, f);
    }
    // The fit's value at the texel is sum of w (g . f) v with g = M^-1 (1, 0, 0).
    // Where the chart cannot fix a plane (one texel wide, a lone texel) it is
    // the taps' weighted mean: g = (1 / sum of w, 0, 0). Where the chart
    // could but the taps alike the texel do not (at 16 texels, a gradient's
    // taps unlike the centre but along one line), a ridge (1e-6 of the
    // weights' sum on the slopes' diagonal) holds the unfixed slope at 0 and
    // the fit is the one the other taps make, exact along that line; the
    // mean there pulled such a texel 0.03 up a gradient of 0.8 across the
    // step. Where both slopes are fixed the ridge moves the value by under
    // 1e-5 of the gradient.
    vec3 g = vec3(1.0 / m[0][0], 0.0, 0.0);
    if (abs(determinant(m_where)) > 1e-6 * m_where[0][0] * m_where[0][0] * m_where[0][0]) {
        float ridge = 1e-6 * m[0][0];
        m[1][1] += ridge;
        m[2][2] += ridge;
        g = inverse(m)[0];
    }

    vec3 sum = vec3(0.0);
    float variance = 0.0;
    for (int t = 0; t < 25; ++t) {
        float k = w[t] * dot(g, vec3(1.0, t % 5 - 2, t / 5 - 2));
        if (k == 0.0) continue;
        vec4 c = colour_in[tap[t]];
        sum += k * c.rgb;
        variance += k * k * c.w;
    }
    // Irradiance is never negative; a fit's extrapolation to a border could
    // be. The low-pass filters a difference of two maps, which may be.
    colour_out[i] = vec4(luminance_weights != 0u ? max(sum, vec3(0.0)) : sum, variance);
}
