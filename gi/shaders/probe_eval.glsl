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
// 6·M·M texel centre distances packed four to a vec4 (0 where the set has
// none), then per texel two vec4 (a split texel's bridge radiance and 1, and
// its nearer plane's corner distances; zero for the others), then the
// probe's 9 SH9 coefficients (RGB; the first three's w its reference point). Probe k starts at vec4
// k · lf_probe_stride(M), at binding LF_BINDING_PROBE_SET.
#ifndef LF_PROBE_EVAL_GLSL
#define LF_PROBE_EVAL_GLSL

#include "buffer_bindings.glsl"
#include "probe_cube.glsl"
#include "sh_basis.glsl"

layout(std430, binding = LF_BINDING_PROBE_SET) readonly buffer LfProbeTexels { vec4 lf_probe_texels[]; };

const float LF_TWO_PI = 6.283185307179586;
// lf::kMissDistance: a texel or corner whose rays escaped the scene.
const float LF_PROBE_MISS = 1e6;

uint lf_probe_stride(int m) {
    return uint(6 * m * m) + uint(6 * (m + 1) * (m + 1) + 3) / 4u + uint(6 * m * m + 3) / 4u + uint(12 * m * m) + 9u;
}

// Where texel t's split (lf::split_bridges) starts: (bridge radiance, 1 if split), then its nearer-plane corner distances.
uint lf_probe_split(uint base, int m, uint t) {
    return base + uint(6 * m * m) + uint(6 * (m + 1) * (m + 1) + 3) / 4u + uint(6 * m * m + 3) / 4u + 2u * t;
}

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

// The texel of the M x M cube grid that direction d (not 0) passes through: (face, i, j).
ivec3 lf_probe_texel_towards(int m, vec3 d) {
    vec3 a = abs(d);
    int axis = a.x >= a.y && a.x >= a.z ? 0 : (a.y >= a.z ? 1 : 2);
    int face = 2 * axis + (d[axis] < 0.0 ? 1 : 0);
    vec2 uv = lf_cube_face_uv(face, d / a[axis]);
    return ivec3(face, clamp(int(uv.x * float(m)), 0, m - 1), clamp(int(uv.y * float(m)), 0, m - 1));
}

// Texel (face, i, j)'s polygon corners relative to the probe, wound as
// lf_probe_polygon_to_point's; false when a corner's own ray met no surface.
bool lf_probe_texel_corners(uint base, int m, ivec3 texel, out vec3 c[4]) {
    const ivec2 corner_of[4] = ivec2[4](ivec2(0, 0), ivec2(0, 1), ivec2(1, 1), ivec2(1, 0));
    bool traced = true;
    for (int k = 0; k < 4; ++k) {
        ivec2 ab = texel.yz + corner_of[k];
        float d = lf_probe_corner_signed(base, m, texel.x, ab.x, ab.y);
        traced = traced && d > 0.0;
        c[k] = abs(d) * lf_cube_direction(texel.x, vec2(ab) / float(m));
    }
    return traced;
}

// The distance from the probe along unit u (in the polygon's cone) to the
// polygon c: the plane of whichever triangle (split along c0-c2) holds u; 0
// where u runs along it (lf::polygon_depth).
float lf_probe_polygon_depth(vec3 c[4], vec3 u) {
    vec3 split = cross(c[0], c[2]);
    vec3 b = dot(split, u) * dot(split, c[1]) >= 0.0 ? c[1] : c[3];
    vec3 normal = cross(b - c[0], c[2] - c[0]);
    float along = dot(normal, u);
    return along == 0.0 ? 0.0 : dot(normal, c[0]) / along;
}

float lf_probe_polygon_reach(vec3 c[4]) { return max(length(c[2] - c[0]), length(c[3] - c[1])); }

// The texel sees one flat surface: each corner within 10⁻⁴ of its distance
// of the plane through the other three, and so is the point its centre ray
// met where the set has centres (lf::texel_is_flat says why).
bool lf_probe_texel_is_flat(uint base, int m, ivec3 texel, vec3 c[4]) {
    for (int k = 0; k < 4; ++k) {
        vec3 a = c[(k + 1) % 4], b = c[(k + 2) % 4], d = c[(k + 3) % 4];
        vec3 normal = cross(b - a, d - a);
        float len = length(normal);
        if (!(len > 0.0)) return false;
        if (abs(dot(normal / len, c[k] - a)) > 1e-4 * length(c[k])) return false;
    }
    uint t = uint((texel.x * m + texel.z) * m + texel.y);
    float centre = lf_probe_texels[base + uint(6 * m * m) + uint(6 * (m + 1) * (m + 1) + 3) / 4u + t / 4u][t % 4u];
    if (centre == 0.0) return true;  // a set without centres: the corners alone
    if (!(centre < LF_PROBE_MISS)) return false;
    vec3 normal = normalize(cross(c[2] - c[0], c[3] - c[1]));
    vec3 point = centre * lf_cube_direction(texel.x, (vec2(texel.yz) + 0.5) / float(m));
    return abs(dot(normal, point - c[0])) <= 1e-4 * centre;
}

// The polygon's unit normal towards the probe (cross of its diagonals, as lf::prepare_probe).
vec3 lf_probe_polygon_normal(vec3 c[4], vec3 direction) {
    vec3 normal = cross(c[2] - c[0], c[3] - c[1]);
    float len = length(normal);
    normal = len > 0.0 ? normal / len : -direction;
    return dot(normal, -direction) < 0.0 ? -normal : normal;
}

float lf_probe_on_surface_tolerance(float distance) { return 2e-4 * distance + 5e-5; }

// x, or where x lies beyond the polygon the probe sees towards it by at most
// the polygon's longer diagonal (between a polygon that cuts across a room's
// edge and the edge), the point just inside that polygon on the line from the
// probe to x: lf::probe_point_inside, which says why.
vec3 lf_probe_point_inside(uint base, int m, vec3 probe_position, vec3 x) {
    vec3 r = x - probe_position;
    float distance = length(r);
    if (!(distance > 0.0)) return x;
    vec3 c[4];
    if (!lf_probe_texel_corners(base, m, lf_probe_texel_towards(m, r), c)) return x;  // a corner placed by a rule
    float wall = lf_probe_polygon_depth(c, r / distance);
    if (!(wall > 0.0) || distance <= wall || distance - wall > lf_probe_polygon_reach(c)) return x;
    return probe_position + r * (wall / distance * (1.0 - 1e-4));
}

// Whether the probe sees x, from its own distances texel by texel:
// lf::probe_sees, which says how (a flat texel exactly; a texel across a
// room's inner edge by the planes of the flat texels beside it; otherwise up
// to the polygon's diagonal beyond it).
bool lf_probe_sees(uint base, int m, vec3 probe_position, vec3 x) {
    vec3 r = x - probe_position;
    float distance = length(r);
    if (!(distance > 0.0)) return true;
    ivec3 texel = lf_probe_texel_towards(m, r);
    float tolerance = lf_probe_on_surface_tolerance(distance);
    vec3 c[4];
    if (!lf_probe_texel_corners(base, m, texel, c)) {
        float stored = lf_probe_texels[base + uint((texel.x * m + texel.z) * m + texel.y)].w;
        if (stored >= LF_PROBE_MISS) return true;
        float farthest = stored;
        for (int k = 0; k < 4; ++k)
            if (length(c[k]) < 0.5 * LF_PROBE_MISS) farthest = max(farthest, length(c[k]));
        return distance <= farthest + lf_probe_polygon_reach(c);
    }
    float wall = lf_probe_polygon_depth(c, r / distance);
    if (lf_probe_texel_is_flat(base, m, texel, c)) return !(wall > 0.0) || distance <= wall + tolerance;
    // The flat texels across the four edges and the four corners: the planes
    // of the walls whose edge this texel sees.
    float inv_m = 1.0 / float(m);
    vec3 centre = lf_cube_direction(texel.x, (vec2(texel.yz) + 0.5) * inv_m);
    const ivec2 corner_of[4] = ivec2[4](ivec2(0, 0), ivec2(0, 1), ivec2(1, 1), ivec2(1, 0));
    vec3 plane_point[8], plane_normal[8];
    int planes = 0;
    for (int k = 0; k < 8; ++k) {
        vec3 mid = normalize(lf_cube_direction(texel.x, vec2(texel.yz + corner_of[k % 4]) * inv_m) +
                             lf_cube_direction(texel.x, vec2(texel.yz + corner_of[(k + k / 4) % 4]) * inv_m));
        ivec3 beside = lf_probe_texel_towards(m, mid + 0.5 * (mid - centre));
        vec3 nc[4];
        if (beside == texel || !lf_probe_texel_corners(base, m, beside, nc) || !lf_probe_texel_is_flat(base, m, beside, nc))
            continue;
        plane_point[planes] = nc[0];
        plane_normal[planes] = lf_probe_polygon_normal(nc, lf_cube_direction(beside.x, (vec2(beside.yz) + 0.5) * inv_m));
        ++planes;
    }
    bool inner = planes > 0;
    for (int p = 0; p < planes; ++p)
        for (int k = 0; k < 4; ++k)
            inner = inner && dot(plane_normal[p], c[k] - plane_point[p]) >=
                                 -lf_probe_on_surface_tolerance(length(plane_point[p]));
    if (inner) {
        for (int p = 0; p < planes; ++p)
            if (dot(plane_normal[p], r - plane_point[p]) < -tolerance) return false;
        return true;
    }
    return !(wall > 0.0) || distance <= wall + lf_probe_polygon_reach(c);
}

// The form factor from x (unit normal n) to the quad r0..r3 (relative to
// x), as its two triangles split along r0-r2, each clipped to x's horizon,
// signed (lf::clipped_texel_form_factor).
float lf_clipped_quad_form_factor(vec3 r0, vec3 r1, vec3 r2, vec3 r3, vec3 n) {
    vec4 h = vec4(dot(n, r0), dot(n, r1), dot(n, r2), dot(n, r3));
    if (all(lessThan(h, vec4(0.0)))) return 0.0;  // below the horizon
    if (all(greaterThanEqual(h, vec4(0.0))))       // above: the two triangles' shared edge cancels
        return (lf_edge_term(r0, r1, n) + lf_edge_term(r1, r2, n) + lf_edge_term(r2, r3, n) + lf_edge_term(r3, r0, n)) /
               LF_TWO_PI;
    return lf_clipped_triangle_form_factor(r0, r1, r2, n) + lf_clipped_triangle_form_factor(r0, r2, r3, n);
}

// Irradiance / π at x (unit normal n) from probe `probe` (index into the
// buffer, M texels per face side, reference point probe_position): every
// texel a quad with corners at the corner distances, as its two triangles
// split along corners 0-2, each clipped to x's horizon; Σ L_i · F_i signed,
// clamped at 0 in total (lf::probe_polygon_to_point says why). A split
// texel's quad carries the bridge's radiance and its nearer plane's quad
// the rest (lf::split_bridges).
vec3 lf_probe_polygon_to_point(uint probe, int m, vec3 probe_position, vec3 x, vec3 n) {
    uint base = probe * lf_probe_stride(m);
    float inv_m = 1.0 / float(m);
    x = lf_probe_point_inside(base, m, probe_position, x);
    vec3 sum = vec3(0.0);
    const ivec2 corner_of[4] = ivec2[4](ivec2(0, 0), ivec2(0, 1), ivec2(1, 1), ivec2(1, 0));
    for (int face = 0; face < 6; ++face)
        for (int j = 0; j < m; ++j)
            for (int i = 0; i < m; ++i) {
                uint t = uint((face * m + j) * m + i);
                vec3 radiance = lf_probe_texels[base + t].rgb;
                vec4 split = lf_probe_texels[lf_probe_split(base, m, t)];
                if (radiance == vec3(0.0) && split.w == 0.0) continue;
                // (i, j), (i, j+1), (i+1, j+1), (i+1, j): counter-clockwise about the outward direction.
                vec3 d[4], r[4];
                for (int k = 0; k < 4; ++k) {
                    ivec2 ab = ivec2(i, j) + corner_of[k];
                    d[k] = lf_cube_direction(face, vec2(ab) * inv_m);
                    r[k] = probe_position + lf_probe_corner_distance(base, m, face, ab.x, ab.y) * d[k] - x;
                }
                vec3 bridge = split.w > 0.0 ? split.rgb : radiance;
                if (bridge != vec3(0.0)) sum += bridge * lf_clipped_quad_form_factor(r[0], r[1], r[2], r[3], n);
                if (split.w > 0.0 && radiance != bridge) {
                    vec4 near = lf_probe_texels[lf_probe_split(base, m, t) + 1u];
                    vec3 q = probe_position - x;
                    sum += (radiance - bridge) * lf_clipped_quad_form_factor(q + near.x * d[0], q + near.y * d[1],
                                                                             q + near.z * d[2], q + near.w * d[3], n);
                }
            }
    return max(sum, vec3(0.0));
}

// ----------------------------------------------------------- a grid ----
// A lattice of probes (the bake's grid placement): counts.x × counts.y ×
// counts.z probes, probe (ix, iy, iz) at lattice point origin + (ix, iy,
// iz) · spacing (the blend's weights) and at index (iz·counts.y +
// iy)·counts.x + ix in the buffer (x fastest, the order probes.json lists a
// grid in); its light is evaluated from its reference point (the lattice
// point, or where the bake moved it). An invalid probe's block is zero, so
// its first texel's distance is 0 (a valid texel's never is).

bool lf_probe_valid(uint probe, int m) { return lf_probe_texels[probe * lf_probe_stride(m)].w > 0.0; }

// Where the probe's cube maps were taken: its lattice point, or where the
// bake moved it away from a surface (lf::Probe::moved_from).
vec3 lf_probe_reference_point(uint probe, int m) {
    uint base = (probe + 1u) * lf_probe_stride(m) - 9u;
    return vec3(lf_probe_texels[base].w, lf_probe_texels[base + 1u].w, lf_probe_texels[base + 2u].w);
}

// When no corner of x's cell is valid and sees x: the nearest valid probes
// that see it (up to 8), weighted ((r − d) / (r·d))² with r the distance of
// the next one (or 1.5 × the farthest's when there is no next), as
// lf::ProbeEvaluator::visible_weights; 0 when no probe sees x.
vec3 lf_probe_grid_nearest(ivec3 counts, int m, vec3 x, vec3 n) {
    float d[9];
    int k9[9];
    int found = 0;
    for (int k = 0; k < counts.x * counts.y * counts.z; ++k) {
        if (!lf_probe_valid(uint(k), m)) continue;
        vec3 position = lf_probe_reference_point(uint(k), m);
        if (!lf_probe_sees(uint(k) * lf_probe_stride(m), m, position, x)) continue;
        float dk = length(position - x);
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
        return lf_probe_polygon_to_point(uint(k9[0]), m, lf_probe_reference_point(uint(k9[0]), m), x, n);
    int count = min(found, 8);
    float radius = count < found ? d[count] : d[count - 1] * 1.5;
    vec3 sum = vec3(0.0);
    float total = 0.0;
    for (int i = 0; i < count; ++i) {
        float w = pow(max(0.0, radius - d[i]) / (radius * d[i]), 2.0);
        if (w <= 0.0) continue;
        sum += w * lf_probe_polygon_to_point(uint(k9[i]), m, lf_probe_reference_point(uint(k9[i]), m), x, n);
        total += w;
    }
    if (total > 0.0) return sum / total;
    for (int i = 0; i < count; ++i)  // every one as far as the next: equal weights
        sum += lf_probe_polygon_to_point(uint(k9[i]), m, lf_probe_reference_point(uint(k9[i]), m), x, n);
    return sum / float(count);
}

// Irradiance / π at (x, n) from a grid: the valid corners of x's cell that
// see x (lf_probe_sees) blended trilinearly (weights renormalised over
// them), the nearest valid probes that see x where none of the cell's
// does, as the C++ lf::ProbeEvaluator does for a lattice.
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
        vec3 position = lf_probe_reference_point(uint(k), m);
        if (!lf_probe_sees(uint(k) * lf_probe_stride(m), m, position, x)) continue;
        sum += w * lf_probe_polygon_to_point(uint(k), m, position, x, n);
        total += w;
    }
    return total > 0.0 ? sum / total : lf_probe_grid_nearest(counts, m, x, n);
}

#endif
