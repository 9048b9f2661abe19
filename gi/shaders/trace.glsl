// The one ray tracer: BVH traversal and watertight ray/triangle tests.
// Every method includes this file and traces from its own shader; the
// scene's BVH is bound at its two binding points (buffer_bindings.glsl),
// and the see-through surfaces' materials beside it (surface_textures.glsl).
//
// Light passes through see-through surfaces (Material::is_see_through):
// where alpha cuts a surface out (MASK), in proportion to 1 - alpha (BLEND),
// and through glass (KHR_materials_transmission) tinted by its colour. The
// queries, for every method alike:
//  * trace_closest: the first surface that stops the ray; each see-through
//    surface before it was passed by a choice drawn with its transmittance's
//    odds (a hash of the ray and the triangle: the same ray chooses alike in
//    every query), and Hit.tint is the colour of the light that came through
//    them (1 on a ray that passed none): light from the hit, or from the sky
//    on a miss, arrives times tint. Unbiased: the choice's expected weight
//    is the transmittance (Scene::transmittance_at).
//  * trace_transmittance: the share of light that passes from the origin to
//    t_max, per channel, as an expectation: 0 past an opaque surface, the
//    product of the transmittances past see-through ones. Shadow rays.
//  * trace_occluded: whether something stops the ray, see-through surfaces
//    passed by the same choice as trace_closest (a yes/no estimate, for
//    occlusion counts).
//  * trace_closest_geometry, trace_occluded_geometry: every triangle stops
//    the ray: where geometry is, not how light passes (texel placement).
#ifndef LF_TRACE_GLSL
#define LF_TRACE_GLSL

// LF_SEE_THROUGH: 1 where the scene has a see-through surface, 0 where it
// has none and the traversal leaves the material code out (Tracer::program).
#ifndef LF_SEE_THROUGH
#error "a program that traces is built by Tracer::program (LF_SEE_THROUGH)"
#endif

#include "buffer_bindings.glsl"
#include "bvh_layout.glsl"
#include "random.glsl"
#include "surface_textures.glsl"

// BvhNode (64 bytes, 4-wide; trace/bvh.h): the low corner of the node's box
// and its three steps' exponents; the children's planes, one byte each, in
// steps from that corner (lo_x, hi_x, lo_y, hi_y, lo_z, hi_z); their
// triangle counts (16 bits each); their indices.
layout(std430, binding = LF_BINDING_BVH_NODES) readonly buffer LfBvhNodes { uvec4 lf_bvh_nodes[]; };
// BvhTriangle (48 bytes): v0 (w = scene triangle index bits), v1, v2.
layout(std430, binding = LF_BINDING_BVH_TRIANGLES) readonly buffer LfBvhTriangles { vec4 lf_bvh_tris[]; };

const uint LF_NO_HIT = 0xffffffffu;

struct Hit {
    float t;
    uint triangle;  // scene triangle index, LF_NO_HIT on a miss
    vec2 bary;      // (b1, b2): weights of the triangle's 2nd and 3rd vertex
    bool front;     // the ray met the side the triangle's counter-clockwise normal faces
    vec3 normal;    // the triangle's geometric normal (counter-clockwise), not normalized
    vec3 tint;      // trace_closest: the light through the see-through surfaces the ray passed
};

// Per-ray constants of the watertight test (Woop, Benthin & Wald 2013):
// the axis the ray mostly follows becomes z, and a shear maps the ray to +z.
struct RayShear {
    ivec3 k;    // kx, ky, kz
    vec3 s;     // Sx, Sy, Sz
};

RayShear ray_shear(vec3 dir) {
    vec3 a = abs(dir);
    int kz = (a.x > a.y) ? ((a.x > a.z) ? 0 : 2) : ((a.y > a.z) ? 1 : 2);
    int kx = (kz + 1) % 3;
    int ky = (kx + 1) % 3;
    if (dir[kz] < 0.0) { int tmp = kx; kx = ky; ky = tmp; }  // keep the winding
    RayShear r;
    r.k = ivec3(kx, ky, kz);
    r.s = vec3(dir[kx] / dir[kz], dir[ky] / dir[kz], 1.0 / dir[kz]);
    return r;
}

// Watertight: a ray through a shared edge or vertex hits at least one of the
// triangles that share it (edge functions are evaluated identically for both).
// On a hit with t_min < t < t_max, returns true and sets t and (b1, b2).
bool intersect_triangle(vec3 org, RayShear sh, vec3 v0, vec3 v1, vec3 v2, float t_min, float t_max,
                        out float t, out vec2 bary) {
    vec3 A = v0 - org, B = v1 - org, C = v2 - org;
    float Ax = A[sh.k.x] - sh.s.x * A[sh.k.z];
    float Ay = A[sh.k.y] - sh.s.y * A[sh.k.z];
    float Bx = B[sh.k.x] - sh.s.x * B[sh.k.z];
    float By = B[sh.k.y] - sh.s.y * B[sh.k.z];
    float Cx = C[sh.k.x] - sh.s.x * C[sh.k.z];
    float Cy = C[sh.k.y] - sh.s.y * C[sh.k.z];
    float U = Cx * By - Cy * Bx;
    float V = Ax * Cy - Ay * Cx;
    float W = Bx * Ay - By * Ax;
    t = 0.0; bary = vec2(0.0);
    if ((U < 0.0 || V < 0.0 || W < 0.0) && (U > 0.0 || V > 0.0 || W > 0.0)) return false;
    float det = U + V + W;
    if (det == 0.0) return false;
    float Az = sh.s.z * A[sh.k.z], Bz = sh.s.z * B[sh.k.z], Cz = sh.s.z * C[sh.k.z];
    float T = U * Az + V * Bz + W * Cz;
    float inv_det = 1.0 / det;
    t = T * inv_det;
    if (!(t > t_min && t < t_max)) return false;
    bary = vec2(V, W) * inv_det;
    return true;
}

const float LF_INFINITY = uintBitsToFloat(0x7f800000u);

// The four bytes of a plane word, child c's in component c.
vec4 lf_plane_steps(uint word) { return vec4((uvec4(word) >> uvec4(0u, 8u, 16u, 24u)) & 0xffu); }

// Entry distances of the ray into a node's four child boxes, +infinity for
// a box it misses. A plane q steps from the node's corner is met at
// t = (corner - org) / dir + q step / dir: one multiply-add per plane.
// Rounding must never drop a box whose face a ray grazes (a ray through a
// vertex on the box's surface must still reach the triangles), so each
// axis's interval is widened on both ends by more than the rounding error
// of its sums: a few ulps of their terms, |corner - org| / |dir| and
// 255 step / |dir| (the relative push of Ize 2013, "Robust BVH Ray
// Traversal", covers only errors proportional to t, and these terms may
// cancel; one axis's entry is compared with another's exit, so both ends
// need it). Unused child slots are the caller's to skip.
vec4 intersect_boxes(vec3 org, vec3 inv_dir, uvec4 corner_steps, uvec4 planes_xy, uvec2 planes_z, float t_min,
                     float t_max) {
    vec3 t_corner = (uintBitsToFloat(corner_steps.xyz) - org) * inv_dir;
    uvec3 exponents = (uvec3(corner_steps.w) >> uvec3(0u, 8u, 16u)) & 0xffu;
    vec3 t_step = uintBitsToFloat(exponents << 23u) * inv_dir;  // 2^(e - 127) / dir
    vec4 tx0 = lf_plane_steps(planes_xy.x) * t_step.x + t_corner.x, tx1 = lf_plane_steps(planes_xy.y) * t_step.x + t_corner.x;
    vec4 ty0 = lf_plane_steps(planes_xy.z) * t_step.y + t_corner.y, ty1 = lf_plane_steps(planes_xy.w) * t_step.y + t_corner.y;
    vec4 tz0 = lf_plane_steps(planes_z.x) * t_step.z + t_corner.z, tz1 = lf_plane_steps(planes_z.y) * t_step.z + t_corner.z;
    vec3 slack = 4e-7 * (abs(t_corner) + 255.0 * abs(t_step));  // > 6 ulps of each axis's terms
    vec4 t_enter = max(max(min(tx0, tx1) - slack.x, min(ty0, ty1) - slack.y), max(min(tz0, tz1) - slack.z, vec4(t_min)));
    vec4 t_exit = min(min(max(tx0, tx1) + slack.x, max(ty0, ty1) + slack.y), min(max(tz0, tz1) + slack.z, vec4(t_max)));
    t_exit *= 1.0000004;
    return mix(vec4(LF_INFINITY), t_enter, lessThanEqual(t_enter, t_exit));
}

vec3 safe_inverse(vec3 d) {
    const float tiny = 1e-30;
    return 1.0 / vec3(abs(d.x) > tiny ? d.x : (d.x < 0.0 ? -tiny : tiny),
                      abs(d.y) > tiny ? d.y : (d.y < 0.0 ? -tiny : tiny),
                      abs(d.z) > tiny ? d.z : (d.z < 0.0 ? -tiny : tiny));
}

// One compare-exchange of a sorting network: slots a < b by entry distance.
void lf_order(inout vec4 t, inout uvec4 node, int a, int b) {
    if (t[b] < t[a]) {
        float t_a = t[a];
        t[a] = t[b];
        t[b] = t_a;
        uint node_a = node[a];
        node[a] = node[b];
        node[b] = node_a;
    }
}

// What a traversal looks for (see the queries at the top).
const uint LF_QUERY_CLOSEST = 0u;       // the closest triangle
const uint LF_QUERY_ANY = 1u;           // any triangle
const uint LF_QUERY_GEOMETRY = 2u;      // flag: every triangle counts, see-through or not (texel placement)
const uint LF_QUERY_SEE_THROUGH = 4u;   // flag: the see-through triangles only (lf_walk_see_through)

// A hash of the ray, for its see-through choices.
uint lf_ray_hash(vec3 org, vec3 dir) {
    uvec3 o = floatBitsToUint(org), d = floatBitsToUint(dir);
    return pcg_hash(o.x ^ pcg_hash(o.y ^ pcg_hash(o.z ^ pcg_hash(d.x ^ pcg_hash(d.y ^ pcg_hash(d.z))))));
}

// Where a ray meets a see-through surface: its material and t to 2^-13. A
// ray through an edge or a vertex meets every triangle that shares it (the
// watertight test's promise), but they are one surface there: met once, by
// one choice (a sun straight down through a window's diagonal, on texels'
// sample points in a row, found it squared).
uint lf_surface_key(uint triangle, float t) {
    return pcg_hash(surface_material(triangle) ^ pcg_hash(floatBitsToUint(t) >> 10u));
}

// A see-through surface's choice for one ray: passed (true, with the
// light's tint: 1 through a hole, the glass's colour through glass) or not.
// u is uniform per ray and surface point (lf_surface_key): passed with odds
// 1 - coverage (a hole) plus coverage x transmission (glass), so the
// expected tint is Scene::transmittance_at. The glass branch's tint is base
// colour x absorption, its odds the transmission factor: their product is
// the glass's transmittance.
bool lf_passes(uint triangle, vec2 bary, uint choice, out vec3 tint) {
    float coverage;
    vec3 transmitted;
    surface_see_through(triangle, bary, coverage, transmitted);
    float u = float(pcg_hash(choice) >> 8) * (1.0 / 16777216.0);
    float odds = material_float(surface_material(triangle), LF_MAT_TRANSMISSION);
    tint = u < 1.0 - coverage ? vec3(1.0) : (odds > 0.0 ? transmitted / odds : vec3(0.0));
    return u < 1.0 - coverage + coverage * odds;
}

// The traversal, shared by every query: the closest triangle (or with
// LF_QUERY_ANY the first found) with t_min < t < t_max. It never evaluates a
// material: a see-through triangle (marked by the Tracer) is passed over,
// its distance kept in see_through_t (the nearest such, +infinity if none;
// the caller then walks them, lf_walk_see_through), and under
// LF_QUERY_SEE_THROUGH it is the other way round. Material code in the
// leaf loop cost every ray its registers, see-through or not: the real
// interiors traced at 0.4-0.5x the rays/s on llvmpipe with it there
// (docs/BENCHMARKS.md, "No material code in the traversal").
// With LF_QUERY_SEE_THROUGH, `passed` are triangles the walk has met at
// t_min already (LF_NO_HIT for none): passed over, while t_min itself counts
// as a hit when they are given, so that a second surface at the same place
// (a slab's face on the next slab's, a sheet on a pane) is met too.
Hit lf_traverse(vec3 org, vec3 dir, float t_min, float t_max, uint query, uvec4 passed, out float see_through_t) {
    Hit hit = Hit(t_max, LF_NO_HIT, vec2(0.0), false, vec3(0.0), vec3(1.0));
    see_through_t = LF_INFINITY;
    bool materials = (query & LF_QUERY_GEOMETRY) == 0u;
    bool walking = (query & LF_QUERY_SEE_THROUGH) != 0u;
    bool any_hit = (query & LF_QUERY_ANY) != 0u;
    // t_min inclusive for the walk past surfaces it met there (boxes and
    // triangles alike: a flat node ends exactly there): the float just below it.
    float t_low = walking && passed.x != LF_NO_HIT ? uintBitsToFloat(floatBitsToUint(t_min) - 1u) : t_min;
    RayShear sh = ray_shear(dir);
    vec3 inv_dir = safe_inverse(dir);
    uint stack[LF_BVH_STACK_SIZE];
    float stack_t[LF_BVH_STACK_SIZE];
    int sp = 0;
    uint node = 0u;
    while (true) {
        uint base = LF_BVH_NODE_UVEC4S * node;
        uvec4 planes_z_counts = lf_bvh_nodes[base + 2u];
        uvec4 child = lf_bvh_nodes[base + 3u];
        uvec4 count = (planes_z_counts.zzww >> uvec4(0u, 16u, 0u, 16u)) & 0xffffu;
        vec4 t_enter = intersect_boxes(org, inv_dir, lf_bvh_nodes[base], lf_bvh_nodes[base + 1u],
                                       planes_z_counts.xy, t_low, hit.t);
        t_enter = mix(t_enter, vec4(LF_INFINITY), equal(child | count, uvec4(0u)));  // unused slots
        // Leaves are tested right away; only interior children are traversed.
        for (int c = 0; c < 4; ++c) {
            if (t_enter[c] == LF_INFINITY || count[c] == 0u) continue;
            t_enter[c] = LF_INFINITY;
            for (uint i = child[c]; i < child[c] + count[c]; ++i) {
                float t; vec2 b;
                vec4 w0 = lf_bvh_tris[3u * i], w1 = lf_bvh_tris[3u * i + 1u];
#if LF_SEE_THROUGH
                bool see_through = materials && floatBitsToUint(w1.w) != 0u;
                if (walking && !see_through) continue;
#endif
#if LF_SEE_THROUGH
                if (walking && any(equal(uvec4(floatBitsToUint(w0.w)), passed))) continue;
#endif
                vec3 v0 = w0.xyz, v1 = w1.xyz, v2 = lf_bvh_tris[3u * i + 2u].xyz;
                if (!intersect_triangle(org, sh, v0, v1, v2, t_low, hit.t, t, b)) continue;
#if LF_SEE_THROUGH
                if (see_through && !walking) {
                    see_through_t = min(see_through_t, t);
                    continue;
                }
#endif
                vec3 ng = cross(v1 - v0, v2 - v0);
                hit = Hit(t, floatBitsToUint(w0.w), b, dot(ng, dir) < 0.0, ng, vec3(1.0));
                if (any_hit) return hit;
            }
        }
        // Interior children that start before the closest hit so far, nearest
        // first (a sorting network): the nearest is visited next, the others
        // wait on the stack. LF_QUERY_ANY takes any hit, in any order.
        t_enter = mix(t_enter, vec4(LF_INFINITY), greaterThan(t_enter, vec4(hit.t)));
        if (!any_hit) {
            lf_order(t_enter, child, 0, 1);
            lf_order(t_enter, child, 2, 3);
            lf_order(t_enter, child, 0, 2);
            lf_order(t_enter, child, 1, 3);
            lf_order(t_enter, child, 1, 2);
        }
        for (int c = 3; c > 0; --c) {
            if (t_enter[c] != LF_INFINITY) {
                stack_t[sp] = t_enter[c];
                stack[sp++] = child[c];
            }
        }
        if (t_enter[0] != LF_INFINITY) {
            node = child[0];
        } else {
            // A node that starts beyond the closest hit found since it was pushed is skipped.
            while (sp > 0 && stack_t[sp - 1] > hit.t) --sp;
            if (sp == 0) break;
            node = stack[--sp];
        }
    }
    return hit;
}

Hit lf_traverse(vec3 org, vec3 dir, float t_min, float t_max, uint query, out float see_through_t) {
    return lf_traverse(org, dir, t_min, t_max, query, uvec4(LF_NO_HIT), see_through_t);
}

#if LF_SEE_THROUGH
// The volume a ray is inside (KHR_materials_volume, Material::attenuation),
// for Beer-Lambert over the path in it: its absorption per unit of t and
// the t where the ray entered it.
struct LfMedium {
    vec3 attenuation;  // 0: outside every volume
    float since;
    uint material;     // whose volume it is
    bool crossed;      // a volume's surface was crossed (before it, the origin may be inside one)
};

// A ray passes see-through surface s: the light is absorbed over the path
// in the medium up to s.t, and the medium changes where s bounds a volume
// whose triangles close (Scene::closed_volumes): a front face is the way in,
// a back face the way out. A back face met before any volume's surface:
// the ray started inside (a bounce off something in the glass), so the
// path in it starts at the origin. Leaving a volume other than the one the
// ray is in (two that touch, the next one's front face met first at the
// same point) keeps the ray in the one it entered. A volume's open sheet absorbs over its
// thicknessFactor at each crossing (the glTF spec's approximation). Not
// followed: a ray between two opaque surfaces inside a volume, which meets
// no see-through surface and so is not walked (light bounced inside a glass
// block is not absorbed on that leg).
void lf_cross_medium(Hit s, float dir_length, inout LfMedium medium, inout vec3 tint) {
    uint m = surface_material(s.triangle);
    vec3 attenuation = material_vec3(m, LF_MAT_ATTENUATION);
    if (attenuation == vec3(0.0)) return;
    float open_thickness = material_float(m, LF_MAT_OPEN_THICKNESS);
    if (open_thickness > 0.0) {
        tint *= exp(-attenuation * open_thickness);
        return;
    }
    attenuation *= dir_length;
    tint *= exp(-(medium.crossed || s.front ? medium.attenuation : attenuation) * (s.t - medium.since));
    if (s.front) medium = LfMedium(attenuation, s.t, m, true);
    else if (!medium.crossed || medium.material == m) medium = LfMedium(vec3(0.0), s.t, m, true);
    else medium.since = s.t;
}

// The see-through surfaces along org + t dir before t_max, nearest first,
// each met once (lf_surface_key), one traversal each (LF_QUERY_SEE_THROUGH,
// past the last one met): with `expected`, tint is multiplied by each one's
// transmittance (the expectation: shadow rays) and the walk ends where it
// reaches 0; without, each surface's choice decides (lf_passes): passed,
// tint times its draw's tint; stopped, that surface is returned, tint in
// its Hit.tint. Returns LF_NO_HIT where nothing stopped the ray. Inside a
// volume the light is absorbed over the path (lf_cross_medium), up to t_max
// where the ray ends inside it (a surface within the glass).
Hit lf_walk_see_through(vec3 org, vec3 dir, float t_max, bool expected, inout vec3 tint) {
    uint ray = lf_ray_hash(org, dir);
    uvec2 counted = uvec2(0u);  // the last two surface points met
    float t_min = 0.0, unused;
    // The triangles met at t_min: the next traversal passes over them but not
    // over another surface there. Past four (a fan of one surface's triangles
    // through a vertex) the walk goes on beyond t_min.
    uvec4 met = uvec4(LF_NO_HIT);
    LfMedium medium = LfMedium(vec3(0.0), 0.0, LF_NO_HIT, false);
    while (true) {
        Hit s = lf_traverse(org, dir, t_min, t_max, LF_QUERY_CLOSEST | LF_QUERY_SEE_THROUGH,
                            met.w == LF_NO_HIT ? met : uvec4(LF_NO_HIT), unused);
        if (s.triangle == LF_NO_HIT) {
            if (medium.attenuation != vec3(0.0)) tint *= exp(-medium.attenuation * (t_max - medium.since));
            return s;
        }
        if (s.t == t_min && met.w == LF_NO_HIT) {
            met = met.x == LF_NO_HIT ? uvec4(s.triangle, met.yzw)
                : met.y == LF_NO_HIT ? uvec4(met.x, s.triangle, met.zw)
                : met.z == LF_NO_HIT ? uvec4(met.xy, s.triangle, met.w)
                                     : uvec4(met.xyz, s.triangle);
        } else {
            met = uvec4(s.triangle, LF_NO_HIT, LF_NO_HIT, LF_NO_HIT);
        }
        t_min = s.t;
        uint key = lf_surface_key(s.triangle, s.t);
        if (key == counted.x || key == counted.y) continue;  // the same surface point, another triangle
        counted = uvec2(key, counted.x);
        lf_cross_medium(s, length(dir), medium, tint);
        vec3 drawn;
        if (expected) {
            float coverage;
            vec3 transmitted;
            surface_see_through(s.triangle, s.bary, coverage, transmitted);
            tint *= vec3(1.0 - coverage) + coverage * transmitted;
            if (tint == vec3(0.0)) return s;
        } else if (lf_passes(s.triangle, s.bary, key ^ ray, drawn)) {
            tint *= drawn;
        } else {
            s.tint = tint;
            return s;
        }
    }
    return Hit(t_max, LF_NO_HIT, vec2(0.0), false, vec3(0.0), tint);  // not reached
}
#endif

// Closest hit along org + t dir, 0 < t < t_max, that stops the ray (dir
// need not be unit length; t is in units of |dir|), with the tint of the
// light through the see-through surfaces passed on the way; opaque_t is the
// closest surface that no light passes (t_max where there is none), behind
// whatever see-through surface stopped the ray: the probes' distance (a
// sheet that passes light does not move what lies behind it).
Hit trace_closest_and_opaque(vec3 org, vec3 dir, float t_max, out float opaque_t) {
    float see_through_t;
    Hit hit = lf_traverse(org, dir, 0.0, t_max, LF_QUERY_CLOSEST, see_through_t);
    opaque_t = hit.t;
#if LF_SEE_THROUGH
    if (see_through_t < hit.t) {
        vec3 tint = vec3(1.0);
        Hit stopped = lf_walk_see_through(org, dir, hit.t, false, tint);
        if (stopped.triangle != LF_NO_HIT) return stopped;
        hit.tint = tint;
    }
#endif
    return hit;
}

Hit trace_closest(vec3 org, vec3 dir, float t_max) {
    float opaque_t;
    return trace_closest_and_opaque(org, dir, t_max, opaque_t);
}

// The closest surface along org + t dir that no light passes (see-through
// ones passed over, whatever their draw), 0 < t < t_max.
Hit trace_closest_opaque(vec3 org, vec3 dir, float t_max) {
    float unused;
    return lf_traverse(org, dir, 0.0, t_max, LF_QUERY_CLOSEST, unused);
}

// True if something along org + t dir, 0 < t < t_max, stops the ray.
bool trace_occluded(vec3 org, vec3 dir, float t_max) {
    float see_through_t;
    if (lf_traverse(org, dir, 0.0, t_max, LF_QUERY_ANY, see_through_t).triangle != LF_NO_HIT) return true;
#if LF_SEE_THROUGH
    vec3 tint = vec3(1.0);
    if (see_through_t < t_max) return lf_walk_see_through(org, dir, t_max, false, tint).triangle != LF_NO_HIT;
#endif
    return false;
}

// The expected share of light that passes along org + t dir, 0 < t < t_max, per channel.
vec3 trace_transmittance(vec3 org, vec3 dir, float t_max) {
    float see_through_t;
    if (lf_traverse(org, dir, 0.0, t_max, LF_QUERY_ANY, see_through_t).triangle != LF_NO_HIT) return vec3(0.0);
    vec3 tint = vec3(1.0);
#if LF_SEE_THROUGH
    if (see_through_t < t_max) lf_walk_see_through(org, dir, t_max, true, tint);
#endif
    return tint;
}

// The same as trace_closest and trace_occluded with every triangle stopping the ray.
Hit trace_closest_geometry(vec3 org, vec3 dir, float t_max) {
    float unused;
    return lf_traverse(org, dir, 0.0, t_max, LF_QUERY_CLOSEST | LF_QUERY_GEOMETRY, unused);
}
bool trace_occluded_geometry(vec3 org, vec3 dir, float t_max) {
    float unused;
    return lf_traverse(org, dir, 0.0, t_max, LF_QUERY_ANY | LF_QUERY_GEOMETRY, unused).triangle != LF_NO_HIT;
}

// Moves a ray origin on a surface off it along the geometric normal by an
// amount that scales with the coordinates' magnitude, so the surface does not
// shadow itself at any distance from the origin (Wächter & Binder 2019,
// "A Fast and Robust Method for Avoiding Self-Intersection", Ray Tracing Gems ch. 6).
// n must point to the side the ray leaves on.
vec3 offset_ray_origin(vec3 p, vec3 n) {
    const float origin = 1.0 / 32.0;
    const float float_scale = 1.0 / 65536.0;
    const float int_scale = 256.0;
    ivec3 of_i = ivec3(int_scale * n);
    vec3 p_i = intBitsToFloat(floatBitsToInt(p) + ivec3(p.x < 0.0 ? -of_i.x : of_i.x,
                                                           p.y < 0.0 ? -of_i.y : of_i.y,
                                                           p.z < 0.0 ? -of_i.z : of_i.z));
    return vec3(abs(p.x) < origin ? p.x + float_scale * n.x : p_i.x,
                abs(p.y) < origin ? p.y + float_scale * n.y : p_i.y,
                abs(p.z) < origin ? p.z + float_scale * n.z : p_i.z);
}

#endif
