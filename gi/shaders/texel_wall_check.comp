#version 450 core
// After texel_anchor.comp, per covered texel: a texel whose neighbour in the
// atlas gathers behind a wall (the line between their anchors, lifted off
// the surface, is blocked) sits next to that wall. A bilinear lookup near it
// would blend light from both sides, so it is marked (LF_ANCHOR_NEXT_TO_CUT;
// its neighbour marks itself the same way), and a ray landing there gathers
// where it landed instead (reflected_lookup).
layout(local_size_x = 64) in;

#include "radiosity_params.glsl"
#include "lightmap_lookup.glsl"
#include "radiosity_texels.glsl"

void main() {
    uint i = covered_index();
    if (i >= covered_count) return;
    uvec4 texel = covered_texels[i];
    vec4 self = texel_anchors[texel.z];
    if (self.w >= LF_ANCHOR_CUT) return;
    vec3 lift = 0.1 * sample_texel_size(texel.x) * sample_geometric_normal(texel.x);
    int x = int(texel.z % lf_atlas_size().x), y = int(texel.z / lf_atlas_size().x);
    const ivec2 offsets[4] = ivec2[4](ivec2(1, 0), ivec2(-1, 0), ivec2(0, 1), ivec2(0, -1));
    for (int k = 0; k < 4; ++k) {
        ivec2 n = ivec2(x, y) + offsets[k];
        if (n.x < 0 || n.y < 0 || n.x >= int(lf_atlas_size().x) || n.y >= int(lf_atlas_size().y)) continue;
        vec4 other = texel_anchors[uint(n.y) * lf_atlas_size().x + uint(n.x)];
        if (other.w == LF_ANCHOR_UNCOVERED) continue;
        vec3 from = self.xyz + lift;
        if (trace_occluded_geometry(from, other.xyz + lift - from, 1.0)) {
            texel_anchors[texel.z].w = LF_ANCHOR_NEXT_TO_CUT;
            return;
        }
    }
}
