#version 450 core
// After relocation, per covered texel: keep the texel on ONE side of any
// geometry that cuts through its footprint, and record its anchor.
//
// A texel whose footprint straddles a thin wall has sample points on both
// sides; averaged, it would be half lit on the dark side. The sample that
// sees most of the others (short rays between points lifted a tenth of a
// texel off the surface) becomes the reference; samples it cannot see take
// its place. The anchor is where the texel now gathers; w is LF_ANCHOR_CUT
// for a texel that was moved or cut (texel_wall_check.comp marks its
// neighbours LF_ANCHOR_NEXT_TO_CUT), where reflected_lookup does not read
// the map but has the ray gather where it landed, else LF_ANCHOR_COVERED.
layout(local_size_x = 64) in;

#define LF_SAMPLE_POINTS_ACCESS
#define LF_MOVED_SAMPLES
#include "radiosity_params.glsl"
#include "lightmap_lookup.glsl"
#include "radiosity_texels.glsl"

const uint MAX_CHECKED = 16u;

vec3 lifted(uint s) { return sample_position(s) + 0.1 * sample_texel_size(s) * sample_geometric_normal(s); }

bool sees(uint a, uint b) {
    vec3 from = lifted(a);
    return !trace_occluded_geometry(from, lifted(b) - from, 1.0);
}

void main() {
    uint i = covered_index();
    if (i >= covered_count) return;
    uvec4 texel = covered_texels[i];
    uint first = texel.x, count = min(texel.y, MAX_CHECKED);
    bool marked = false;
    for (uint s = first; s < first + texel.y; ++s) marked = marked || sample_was_moved(s);

    // Which samples see which: bit b of visible[a] is set when sample a sees
    // sample b. Seeing is the same segment both ways, so each pair is traced
    // once (half the rays of asking both ways).
    uint visible[MAX_CHECKED];
    for (uint a = 0u; a < count; ++a) visible[a] = 1u << a;
    for (uint a = 0u; a + 1u < count; ++a) {
        for (uint b = a + 1u; b < count; ++b) {
            if (sees(first + a, first + b)) {
                visible[a] |= 1u << b;
                visible[b] |= 1u << a;
            }
        }
    }
    // The reference: the sample that sees the most others (the first of equals).
    uint reference = 0u;
    uint best = 0u;
    for (uint a = 0u; a < count; ++a) {
        uint seen = uint(bitCount(visible[a])) - 1u;
        if (seen > best || a == 0u) { best = seen; reference = a; }
    }
    if (count > 1u && best + 1u < count) {
        // Cut by geometry: samples on the far side take the reference's place.
        for (uint s = 0u; s < count; ++s) {
            if ((visible[reference] & (1u << s)) != 0u) continue;
            for (uint k = 0u; k < 2u; ++k) sample_points[2u * (first + s) + k] = sample_points[2u * (first + reference) + k];
        }
        marked = true;
    }
    reference += first;
    texel_anchors[texel.z] = vec4(sample_position(reference), marked ? LF_ANCHOR_CUT : LF_ANCHOR_COVERED);
}
