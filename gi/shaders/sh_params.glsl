// The parameters of the SH transfer passes (sh_transfer.comp,
// sh_resolve.comp), filled by ShTransferBaker. C++ includes it as
// "shaders/sh_params.glsl".
#ifndef LF_SH_PARAMS_GLSL
#define LF_SH_PARAMS_GLSL
#include "params_block.glsl"

LF_PARAMS_BEGIN(ShTransferParams)
    LF_U32 vertex_count;      // receivers: unique vertices 0 .. vertex_count-1
    LF_U32 pass;              // 0-based: the transfer's pass; sh_resolve.comp: passes done
    LF_U32 samples_per_pass;
    LF_U32 sample_first;      // this dispatch's slice of the pass's samples (see ShTransferBaker::step)
    LF_U32 sample_count;
    LF_U32 seed;
    float near_dist;          // seed §3.1 near clip: occluders closer than this are ignored
    float far_dist;           // seed §3.1 far clip: occluders further than this are ignored
LF_PARAMS_END(ShTransferParams)

#endif
