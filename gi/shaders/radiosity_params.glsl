// The parameters of the radiosity map's programs (radiosity_gather.comp,
// radiosity_totals.comp, radiosity_publish.comp, copy_texels.comp,
// texel_relocate.comp, texel_anchor.comp, texel_wall_check.comp): one block
// for the family, filled by RadiosityMapBaker for each dispatch (each
// program reads its part). C++ includes it as "shaders/radiosity_params.glsl".
#ifndef LF_RADIOSITY_PARAMS_GLSL
#define LF_RADIOSITY_PARAMS_GLSL
#include "params_block.glsl"

LF_PARAMS_BEGIN(RadiosityParams)
    LF_SHADING_PARAMS
    LF_ATLAS_PARAMS
    LF_U32 covered_count;    // covered texels 0 .. covered_count-1 (radiosity_texels.glsl)
    LF_U32 first_pass;       // the dispatch's first pass, 0-based since the bake began
    LF_U32 pass_count;       // passes this dispatch runs (1 under LF_ONE_PASS_PER_DISPATCH)
    LF_U32 end_epoch;        // 1: its last pass ends an epoch (the current indirect estimate becomes "previous")
    LF_U32 seed;
    LF_U32 light_samples;    // emitter samples per texel per pass
    float converged_error;   // > 0: texels whose relative standard error is below this stop tracing
    LF_U32 min_samples;      // before which no texel is called converged
    LF_U32 partials_stride;  // radiosity_totals.comp: vec4s from one pass's partials to the next's
    LF_U32 pair_count;       // copy_texels.comp: (destination, source) pairs
    LF_U32 sample_count;     // texel_relocate.comp: sample points
LF_PARAMS_END(RadiosityParams)

#endif
