// How a program's *_params.glsl declares its parameter block once for GLSL
// and C++ (ComputeProgram::use(params) uploads the C++ struct whole):
//
//   LF_PARAMS_BEGIN(RaybenchParams)
//       LF_U32 ray_count;
//       float t_far;
//   LF_PARAMS_END(RaybenchParams)
//
// GLSL sees a std140 uniform block at LF_BINDING_PARAMS whose fields are
// global names; C++ (which includes it as "shaders/NAME_params.glsl") sees
// a struct in namespace lf. Only 4-byte scalars, so that every offset is
// the same in both; a vector is its components (and a helper function in
// the GLSL that reads it). A program includes one *_params.glsl, before
// the shared files that read its fields.
#ifndef LF_PARAMS_BLOCK_GLSL
#define LF_PARAMS_BLOCK_GLSL

#ifdef __cplusplus
#include <cstdint>
#define LF_U32 uint32_t
#define LF_I32 int32_t
#define LF_PARAMS_BEGIN(Name) \
    namespace lf {            \
    struct Name {
#define LF_PARAMS_END(Name)                                       \
    }                                                             \
    ;                                                             \
    static_assert(alignof(Name) == 4, "4-byte scalars only");     \
    }
#else
#include "buffer_bindings.glsl"
#define LF_U32 uint
#define LF_I32 int
#define LF_PARAMS_BEGIN(Name) layout(std140, binding = LF_BINDING_PARAMS) uniform Name {
#define LF_PARAMS_END(Name) };
#endif

// The fields of every program that shades what its rays hit
// (direct_light.glsl, path_trace.glsl), filled by SceneShading::fill.
#define LF_SHADING_PARAMS                                                     \
    LF_U32 emitter_count;  /* emitter triangles (SceneShading) */             \
    LF_U32 punctual_count; /* glTF punctual lights */                         \
    float far;             /* longer than any ray inside the scene */         \
    LF_ENVIRONMENT_PARAMS

// The fields of every program whose escaping rays see the environment
// (environment.glsl): a uniform sky, or a map it scales.
#define LF_ENVIRONMENT_PARAMS                                                      \
    float background_r; /* the sky's radiance (W/(sr m^2)), or the map's scale */ \
    float background_g;                                                            \
    float background_b;                                                            \
    LF_U32 env_width; /* the equirectangular map's size; 0 x 0: no map */          \
    LF_U32 env_height;                                                             \
    float env_pdf_scale; /* importance sampling's W H / (2 pi^2 total); 0: none */

// The fields of every program that reads the lightmap atlas
// (lightmap_lookup.glsl): its size in texels.
#define LF_ATLAS_PARAMS \
    LF_U32 atlas_width; \
    LF_U32 atlas_height;

#endif
