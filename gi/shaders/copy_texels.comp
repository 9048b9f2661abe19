#version 450 core
// Dilation: copies an atlas-sized buffer's values (reflected radiance,
// texel anchors) from a chart's border texels to the texels just outside it,
// so bilinear lookups near a border stay in the chart.
layout(local_size_x = 64) in;
#include "buffer_bindings.glsl"
#include "radiosity_params.glsl"

layout(std430, binding = LF_BINDING_ATLAS_TEXELS) buffer AtlasTexels { vec4 atlas_texels[]; };
// (destination atlas index, source atlas index)
layout(std430, binding = LF_BINDING_COPY_PAIRS) readonly buffer CopyPairs { uvec2 copy_pairs[]; };

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= pair_count) return;
    atlas_texels[copy_pairs[i].x] = atlas_texels[copy_pairs[i].y];
}
