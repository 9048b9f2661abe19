#version 450 core
// Dilation: copies reflected radiance from a chart's border texel to the
// texels just outside it, so bilinear lookups near a border stay in the chart.
layout(local_size_x = 64) in;

layout(std430, binding = 5) buffer ReflectedRadiance { vec4 reflected_radiance[]; };
// (destination atlas index, source atlas index)
layout(std430, binding = 10) readonly buffer CopyPairs { uvec2 copy_pairs[]; };

uniform uint pair_count;

void main() {
    uint i = gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x;
    if (i >= pair_count) return;
    reflected_radiance[copy_pairs[i].x] = reflected_radiance[copy_pairs[i].y];
}
