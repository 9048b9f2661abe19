// The parameters of the probes' programs (probe_capture.comp,
// probe_corners.comp), filled by ProbesMethod. C++ includes it as
// "shaders/probes_params.glsl".
#ifndef LF_PROBES_PARAMS_GLSL
#define LF_PROBES_PARAMS_GLSL
#include "params_block.glsl"

LF_PARAMS_BEGIN(ProbesParams)
    LF_SHADING_PARAMS
    LF_ATLAS_PARAMS        // unused: the capture traces paths and reads no lightmap (0 x 0)
    LF_U32 texel_count;    // probe_capture.comp: probes x 6 x resolution²
    LF_U32 resolution;     // R: texels per face side
    LF_U32 pass;
    LF_U32 seed;
    LF_U32 corner_count;   // probe_corners.comp: probes x 6 x (M+1)²
    LF_U32 m;              // M: the polygon-to-point grid's cells per face side
    float miss_distance;   // kMissDistance: a corner whose ray leaves the scene
LF_PARAMS_END(ProbesParams)

#endif
