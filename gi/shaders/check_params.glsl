// The parameters of the test programs that call a GLSL function for the
// tests to compare with the C++ (*_check.comp, tests/gpu_fixture.h's
// run_check_program; probe_bench's timing). One block for them all: each
// reads its part. C++ includes it as "shaders/check_params.glsl".
#ifndef LF_CHECK_PARAMS_GLSL
#define LF_CHECK_PARAMS_GLSL
#include "params_block.glsl"

LF_PARAMS_BEGIN(CheckParams)
    LF_U32 item_count;        // cases 0 .. item_count-1
    LF_U32 mode;              // probe_eval_check.comp: which function (its header)
    LF_U32 grid;              // spherical_triangle_check.comp: the reference integral's grid
    LF_I32 m;                 // probe_eval_check.comp: M, the probes' corner grid
    LF_U32 probe;             // ... the probe evaluated
    float probe_position_x;   // ... at its reference point
    float probe_position_y;
    float probe_position_z;
    LF_I32 grid_counts_x;     // ... the probe grid: probes per axis
    LF_I32 grid_counts_y;
    LF_I32 grid_counts_z;
    float grid_origin_x;      // ... its first probe
    float grid_origin_y;
    float grid_origin_z;
    float grid_spacing_x;     // ... from one probe to the next
    float grid_spacing_y;
    float grid_spacing_z;
LF_PARAMS_END(CheckParams)

#endif
