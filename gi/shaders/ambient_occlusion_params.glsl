// The parameters of one dispatch of ambient_occlusion.comp, defined once
// for GLSL and C++ (AmbientOcclusionMethod fills it and uploads it whole):
// a misspelt field is a compile error on both sides, never a uniform that
// is silently not set. Only 4-byte scalars, so std430 and C++ agree on
// every offset. C++ includes it as "shaders/ambient_occlusion_params.glsl".
#ifndef LF_AMBIENT_OCCLUSION_PARAMS_GLSL
#define LF_AMBIENT_OCCLUSION_PARAMS_GLSL

#ifdef __cplusplus
namespace lf {  // the includer has <cstdint>
struct AmbientOcclusionParams {
#define LF_U32 uint32_t
#else
#include "buffer_bindings.glsl"
layout(std430, binding = LF_BINDING_AO_PARAMS) readonly buffer AmbientOcclusionParams {
#define LF_U32 uint
#endif
    LF_U32 point_count;  // sample points 0 .. point_count-1
    LF_U32 first_pass;   // 0-based pass of this dispatch's first ray per point
    LF_U32 pass_count;   // rays per point in this dispatch, one per pass
    LF_U32 seed;
    float distance;      // the AO distance: a surface further than this does not occlude
#undef LF_U32
#ifdef __cplusplus
};
static_assert(sizeof(AmbientOcclusionParams) == 20, "mirrors the GLSL block: 4-byte scalars only");
}  // namespace lf
#else
} ao;
#endif

#endif
