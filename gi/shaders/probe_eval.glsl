// Light-probe evaluation for renderers (issue 11; gi/probes/probe_eval.h is
// the C++ twin, tested equal): the polygon-to-point form factor (Umenhoffer &
// Szirmay-Kalos, eq. 1, each edge with its own pair of corners), one
// probe's polygon-to-point irradiance / π at (x, n), and a grid's, blended.
//
// The probe texels live in an SSBO, as lf::pack_probe_buffer writes it: per
// probe, 6·M·M vec4 texels (radiance RGB, distance), faces +X,-X,+Y,-Y,+Z,-Z,
// rows from the top (texel (f, i, j) at (f·M + j)·M + i), then the 6·(M+1)²
// corner distances (corner (f, a, b) at (f·(M+1) + b)·(M+1) + a) packed four
// to a vec4 (negative where the corner's own ray met no surface), then the
// probe's 9 SH9 coefficients (RGB). Probe k starts at vec4
// k · lf_probe_stride(M), at binding LF_BINDING_PROBE_SET.
#ifndef LF_PROBE_EVAL_GLSL
#define LF_PROBE_EVAL_GLSL

#include "buffer_bindings.glsl"
#include "probe_cube.glsl"
#include "sh_basis.glsl"

layout(std430, binding = LF_BINDING_PROBE_SET) readonly buffer LfProbeTexels { vec4 lf_probe_texels[]; };

const float LF_TWO_PI = 6.283185307179586;

uint lf_probe_stride(int m) { return uint(6 * m * m) + uint(6 * (m + 1) * (m + 1) + 3) / 4u + 9u; }

// Irradiance / π at normal n from the probe's SH9 environment, convolved with
// the clamped cosine (Ramamoorthi & Hanrahan's A_l / π: 1, 2/3, 1/4): the
// paper's first column, which ignores where the point is.
vec3 lf_probe_sh9(uint probe, int m, vec3 n) {
    uint base = (probe + 1u) * lf_probe_stride(m) - 9u;
    vec4 y[4];
    sh_evaluate(normalize(n), y);
    const float band[9] = float[9](1.0, 2.0 / 3.0, 2.0 / 3.0, 2.0 / 3.0, 0.25, 0.25, 0.25, 0.25, 0.25);
    vec3 e = vec3(0.0);
    for (int c = 0; c < 9; ++c) e += lf_probe_texels[base + uint(c)].rgb * (band[c] * y[c / 4][c % 4]);
    return e;
}

// One edge's term of Lambert's formula: angle(a, b) · n · unit(a × b).
float lf_edge_term(vec3 a, vec3 b, vec3 n) {
    vec3 c = cross(a, b);
    float len = length(c);
    if (!(len > 1e-7 * length(a) * length(b))) return 0.0;  // an edge through x
    return atan(len, dot(a, b)) * dot(c, n) / len;
}

// Form factor from x (unit normal n) to the quad c0..c3, which winds
// counter-clockwise about the direction from x towards it (the other winding
// gives the negative). Exact for a planar quad above x's tangent plane; a quad
// partly below gets the signed-cosine integral (lf_probe_polygon_to_point
// clips instead, and uses this for a quad wholly above).
float lf_polygon_to_point_form_factor(vec3 x, vec3 n, vec3 c0, vec3 c1, vec3 c2, vec3 c3) {
    vec3 r0 = c0 - x, r1 = c1 - x, r2 = c2 - x, r3 = c3 - x;
    float sum = lf_edge_term(r0, r1, n) + lf_edge_term(r1, r2, n) + lf_edge_term(r2, r3, n) + lf_edge_term(r3, r0, n);
    return sum / LF_TWO_PI;
}

// One edge p -> q (relative to x, heights hp, hq above x's horizon) of a
// polygon clipped to that horizon: the part above it, and where it leaves or
// re-enters it (Sutherland–Hodgman, without a corner list).
float lf_clipped_edge_term(vec3 p, vec3 q, float hp, float hq, vec3 n, inout vec3 leaves, inout vec3 enters) {
    if (hp >= 0.0 && hq >= 0.0) return lf_edge_term(p, q, n);
    if (hp < 0.0 && hq < 0.0) return 0.0;
    vec3 crossing = p + (q - p) * (hp / (hp - hq));
    if (hp >= 0.0) {
        leaves = crossing;
        return lf_edge_term(p, crossing, n);
    }
    enters = crossing;
    return lf_edge_term(crossing, q, n);
}

// Form factor from x (unit normal n) to the triangle a, b, c (relative to x)
// clipped to x's horizon, n · r >= 0, signed by its winding as above: exact
// for any planar triangle (lf::clipped_polygon_to_point_form_factor). A
// triangle across the horizon crosses it on two edges; the clipped polygon
// closes along the horizon from where it leaves to where it re-enters.
float lf_clipped_triangle_form_factor(vec3 a, vec3 b, vec3 c, vec3 n) {
    float ha = dot(n, a), hb = dot(n, b), hc = dot(n, c);
    vec3 leaves = vec3(0.0), enters = vec3(0.0);
    float sum = lf_clipped_edge_term(a, b, ha, hb, n, leaves, enters) +
                lf_clipped_edge_term(b, c, hb, hc, n, leaves, enters) +
                lf_clipped_edge_term(c, a, hc, ha, n, leaves, enters);
    return (sum + lf_edge_term(leaves, enters, n)) / LF_TWO_PI;
}

// As packed: negative where the corner's own ray met no surface (its place
// comes from a rule: lf::pack_probe_buffer).
float lf_probe_corner_signed(uint base, int m, int face, int a, int b) {
    uint c = uint((face * (m + 1) + b) * (m + 1) + a);
    vec4 four = lf_probe_texels[base + uint(6 * m * m) + c / 4u];
    return four[c % 4u];
}

float lf_probe_corner_distance(uint base, int m, int face, int a, int b) {
    return abs(lf_probe_corner_signed(base, m, face, a, b));
}

// Face coordinates (u, v) of p, a point of the cube [-1, 1]³ on `face` (the
// inverse of lf_cube_direction).
vec2 lf_cube_face_uv(int face, vec3 p) {
    vec2 st;
    if (face == 0) st = vec2(-p.z, -p.y);
    else if (face == 1) st = vec2(p.z, -p.y);
    else if (face == 2) st = vec2(p.x, p.z);
    else if (face == 3) st = vec2(p.x, -p.z);
    else if (face == 4) st = vec2(p.x, -p.y);
    else st = vec2(-p.x, -p.y);
    return (st + 1.0) * 0.5;
}

// x, or where x lies beyond the polygon the probe sees towards it by at most
// the polygon's longer diagonal (between a polygon that cuts across a room's
// edge and the edge), the point just inside that polygon on the line from the
// probe to x: lf::probe_point_inside, which says why.
vec3 lf_probe_point_inside(uint base, int m, vec3 probe_position, vec3 x) {
    vec3 r = x - probe_position;
    float distance = length(r);
    if (!(distance > 0.0)) return x;
    vec3 a = abs(r);
    int axis = a.x >= a.y && a.x >= a.z ? 0 : (a.y >= a.z ? 1 : 2);
    int face = 2 * axis + (r[axis] < 0.0 ? 1 : 0);
    vec2 uv = lf_cube_face_uv(face, r / a[axis]);
    int i = clamp(int(uv.x * float(m)), 0, m - 1), j = clamp(int(uv.y * float(m)), 0, m - 1);
    const ivec2 corner_of[4] = ivec2[4](ivec2(0, 0), ivec2(0, 1), ivec2(1, 1), ivec2(1, 0));
    vec3 c[4];
    for (int k = 0; k < 4; ++k) {
        ivec2 ab = ivec2(i, j) + corner_of[k];
        float d = lf_probe_corner_signed(base, m, face, ab.x, ab.y);
        if (!(d > 0.0)) return x;  // a corner placed by a rule, not on a surface
        c[k] = d * lf_cube_direction(face, vec2(ab) / float(m));
    }
    // The polygon as two triangles split along c0-c2; the one whose cone holds r.
    vec3 split = cross(c[0], c[2]);
    vec3 b = dot(split, r) * dot(split, c[1]) >= 0.0 ? c[1] : c[3];
    vec3 normal = cross(b - c[0], c[2] - c[0]);
    float along = dot(normal, r) / distance;
    if (along == 0.0) return x;
    float wall = dot(normal, c[0]) / along;
    float reach = max(length(c[2] - c[0]), length(c[3] - c[1]));
    if (!(wall > 0.0) || distance <= wall || distance - wall > reach) return x;
    return probe_position + r * (wall / distance * (1.0 - 1e-4));
}

// Irradiance / π at x (unit normal n) from probe `probe` (index into the
// buffer, M texels per face side, reference point probe_position): every
// texel a quad with corners at the corner distances, as its two triangles
// split along corners 0-2, each clipped to x's horizon; Σ L_i · F_i signed,
// clamped at 0 in total (lf::probe_polygon_to_point says why).
vec3 lf_probe_polygon_to_point(uint probe, int m, vec3 probe_position, vec3 x, vec3 n) {
    uint base = probe * lf_probe_stride(m);
    float inv_m = 1.0 / float(m);
    x = lf_probe_point_inside(base, m, probe_position, x);
    vec3 sum = vec3(0.0);
    for (int face = 0; face < 6; ++face)
        for (int j = 0; j < m; ++j)
            for (int i = 0; i < m; ++i) {
                vec3 radiance = lf_probe_texels[base + uint((face * m + j) * m + i)].rgb;
                if (radiance == vec3(0.0)) continue;
                // (i, j), (i, j+1), (i+1, j+1), (i+1, j): counter-clockwise about the outward direction.
                vec3 c0 = probe_position + lf_probe_corner_distance(base, m, face, i, j) *
                                               lf_cube_direction(face, vec2(i, j) * inv_m);
                vec3 c1 = probe_position + lf_probe_corner_distance(base, m, face, i, j + 1) *
                                               lf_cube_direction(face, vec2(i, j + 1) * inv_m);
                vec3 c2 = probe_position + lf_probe_corner_distance(base, m, face, i + 1, j + 1) *
                                               lf_cube_direction(face, vec2(i + 1, j + 1) * inv_m);
                vec3 c3 = probe_position + lf_probe_corner_distance(base, m, face, i + 1, j) *
                                               lf_cube_direction(face, vec2(i + 1, j) * inv_m);
                vec3 r0 = c0 - x, r1 = c1 - x, r2 = c2 - x, r3 = c3 - x;
                vec4 h = vec4(dot(n, r0), dot(n, r1), dot(n, r2), dot(n, r3));
                if (all(lessThan(h, vec4(0.0)))) continue;  // below the horizon
                float f;
                if (all(greaterThanEqual(h, vec4(0.0))))  // above: the two triangles' shared edge cancels
                    f = (lf_edge_term(r0, r1, n) + lf_edge_term(r1, r2, n) + lf_edge_term(r2, r3, n) +
                         lf_edge_term(r3, r0, n)) / LF_TWO_PI;
                else
                    f = lf_clipped_triangle_form_factor(r0, r1, r2, n) + lf_clipped_triangle_form_factor(r0, r2, r3, n);
                sum += radiance * f;
            }
    return max(sum, vec3(0.0));
}

// ----------------------------------------------------------- a grid ----
// A lattice of probes (the bake's grid placement): counts.x × counts.y ×
// counts.z probes, probe (ix, iy, iz) at origin + (ix, iy, iz) · spacing and
// at index (iz·counts.y + iy)·counts.x + ix in the buffer (x fastest, the
// order probes.json lists a grid in). An invalid probe's block is zero, so
// its first texel's distance is 0 (a valid texel's never is).

bool lf_probe_valid(uint probe, int m) { return lf_probe_texels[probe * lf_probe_stride(m)].w > 0.0; }

vec3 lf_grid_probe_position(ivec3 counts, vec3 origin, vec3 spacing, int k) {
    ivec3 i = ivec3(k % counts.x, (k / counts.x) % counts.y, k / (counts.x * counts.y));
    return origin + vec3(i) * spacing;
}

// When every corner of x's cell is invalid: the nearest valid probes (up to
// 8), weighted ((r − d) / (r·d))² with r the distance of the next one (or
// 1.5 × the farthest's when there is no next), as lf::ProbeEvaluator::weights.
vec3 lf_probe_grid_nearest(ivec3 counts, vec3 origin, vec3 spacing, int m, vec3 x, vec3 n) {
    float d[9];
    int k9[9];
    int found = 0;
    for (int k = 0; k < counts.x * counts.y * counts.z; ++k) {
        if (!lf_probe_valid(uint(k), m)) continue;
        float dk = length(lf_grid_probe_position(counts, origin, spacing, k) - x);
        int at = min(found, 8);  // insertion into the 9 nearest, sorted
        if (found == 9 && dk >= d[8]) continue;
        while (at > 0 && d[at - 1] > dk) {
            d[at] = d[at - 1];
            k9[at] = k9[at - 1];
            --at;
        }
        d[at] = dk;
        k9[at] = k;
        found = min(found + 1, 9);
    }
    if (found == 0) return vec3(0.0);
    if (d[0] < 1e-6 || found == 1)
        return lf_probe_polygon_to_point(uint(k9[0]), m, lf_grid_probe_position(counts, origin, spacing, k9[0]), x, n);
    int count = min(found, 8);
    float radius = count < found ? d[count] : d[count - 1] * 1.5;
    vec3 sum = vec3(0.0);
    float total = 0.0;
    for (int i = 0; i < count; ++i) {
        float w = pow(max(0.0, radius - d[i]) / (radius * d[i]), 2.0);
        if (w <= 0.0) continue;
        sum += w * lf_probe_polygon_to_point(uint(k9[i]), m, lf_grid_probe_position(counts, origin, spacing, k9[i]), x, n);
        total += w;
    }
    if (total > 0.0) return sum / total;
    for (int i = 0; i < count; ++i)  // every one as far as the next: equal weights
        sum += lf_probe_polygon_to_point(uint(k9[i]), m, lf_grid_probe_position(counts, origin, spacing, k9[i]), x, n);
    return sum / float(count);
}

// Irradiance / π at (x, n) from a grid: the valid corners of x's cell
// blended trilinearly (weights renormalised over the valid ones), the
// nearest valid probes where none of the cell's is, as the C++
// lf::ProbeEvaluator does for a lattice.
vec3 lf_probe_grid_polygon_to_point(ivec3 counts, vec3 origin, vec3 spacing, int m, vec3 x, vec3 n) {
    ivec3 i0 = ivec3(0);
    vec3 f = vec3(0.0);
    for (int a = 0; a < 3; ++a) {
        if (counts[a] == 1) continue;
        float g = (x[a] - origin[a]) / spacing[a];
        i0[a] = clamp(int(floor(g)), 0, counts[a] - 2);
        f[a] = clamp(g - float(i0[a]), 0.0, 1.0);
    }
    vec3 sum = vec3(0.0);
    float total = 0.0;
    for (int corner = 0; corner < 8; ++corner) {
        ivec3 bit = ivec3(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
        if ((bit.x == 1 && counts.x == 1) || (bit.y == 1 && counts.y == 1) || (bit.z == 1 && counts.z == 1)) continue;
        vec3 w3 = mix(vec3(1.0) - f, f, vec3(bit));
        float w = w3.x * w3.y * w3.z;
        ivec3 i = i0 + bit;
        int k = (i.z * counts.y + i.y) * counts.x + i.x;
        if (w <= 0.0 || !lf_probe_valid(uint(k), m)) continue;
        sum += w * lf_probe_polygon_to_point(uint(k), m, origin + vec3(i) * spacing, x, n);
        total += w;
    }
    return total > 0.0 ? sum / total : lf_probe_grid_nearest(counts, origin, spacing, m, x, n);
}

#endif
