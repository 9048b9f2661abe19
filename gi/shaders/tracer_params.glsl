// The parameters of raybench.comp (lightfarm raybench) and trace_rays.comp
// (Tracer::trace): the tracer's own programs. C++ includes it as
// "shaders/tracer_params.glsl".
#ifndef LF_TRACER_PARAMS_GLSL
#define LF_TRACER_PARAMS_GLSL
#include "params_block.glsl"

LF_PARAMS_BEGIN(TracerParams)
    LF_U32 ray_count;
    LF_U32 point_count;   // raybench: surface points the incoherent rays leave from
    LF_U32 mode;          // raybench: 0 = coherent (pinhole grid), 1 = incoherent (cosine from surfaces);
                          // trace_rays: 0 = hits of the geometry, 1 = the light's share that passes
    LF_U32 pass;          // raybench: the dispatch, for its random numbers
    float eye_x;          // raybench: the pinhole
    float eye_y;
    float eye_z;
    float t_far;
    LF_U32 image_width;   // raybench: the coherent rays' image
LF_PARAMS_END(TracerParams)

#endif
