// The parameters of lightmap_denoise.comp (one à-trous step), filled by
// LightmapDenoiser. C++ includes it as "shaders/denoise_params.glsl".
#ifndef LF_DENOISE_PARAMS_GLSL
#define LF_DENOISE_PARAMS_GLSL
#include "params_block.glsl"

LF_PARAMS_BEGIN(DenoiseParams)
    LF_U32 width;      // the atlas, in texels
    LF_U32 height;
    LF_I32 step_size;  // the à-trous step's tap spacing: 1, 2, 4 ...
    // 1: weigh taps by luminance too (the edge-aware filter); 0: by the
    // guide alone (position, normal, chart), a filter that is linear in the
    // colour (the low-pass of LightmapDenoiser's low-frequency restore).
    LF_U32 luminance_weights;
LF_PARAMS_END(DenoiseParams)

#endif
