#version 450 core
// At the end of a run of passes (RadiosityMapBaker's dispatch cells):
// publishes every covered texel's albedo x value as the reflected radiance
// that the next passes' indirect rays read. A dispatch of its own, after the
// gather's: a texel's rays read other texels' values.
layout(local_size_x = 64) in;  // before the includes: they use gl_WorkGroupSize

#include "radiosity_params.glsl"
#include "radiosity_resolve.glsl"

void main() {
    uint i = covered_index();
    if (i < covered_count) publish_texel(i);
}
