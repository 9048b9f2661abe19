// The parameters of sh_reference.comp (the brute-force irradiance that SH
// shading is checked against), filled by reference_irradiance. C++
// includes it as "shaders/sh_reference_params.glsl".
#ifndef LF_SH_REFERENCE_PARAMS_GLSL
#define LF_SH_REFERENCE_PARAMS_GLSL
#include "params_block.glsl"

LF_PARAMS_BEGIN(ShReferenceParams)
    LF_U32 vertex_count;
    LF_U32 samples;           // in this dispatch
    LF_U32 chunk;             // dispatches so far: each adds its samples to the sum
    float weight;             // pi / total samples
    LF_U32 seed;
    LF_ENVIRONMENT_PARAMS     // the environment (environment.glsl)
LF_PARAMS_END(ShReferenceParams)

#endif
