// The parameters of one dispatch of ambient_occlusion.comp, filled by
// AmbientOcclusionMethod. C++ includes it as
// "shaders/ambient_occlusion_params.glsl".
#ifndef LF_AMBIENT_OCCLUSION_PARAMS_GLSL
#define LF_AMBIENT_OCCLUSION_PARAMS_GLSL
#include "params_block.glsl"

LF_PARAMS_BEGIN(AmbientOcclusionParams)
    LF_U32 point_count;  // sample points 0 .. point_count-1
    LF_U32 first_pass;   // 0-based pass of this dispatch's first ray per point
    LF_U32 pass_count;   // rays per point in this dispatch, one per pass
    LF_U32 seed;
    float distance;      // the AO distance: a surface further than this does not occlude
LF_PARAMS_END(AmbientOcclusionParams)

#endif
