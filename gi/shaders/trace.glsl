// The one ray tracer: BVH traversal and watertight ray/triangle tests.
// Every method includes this file and traces from its own shader; the
// scene's BVH is bound at its two binding points (buffer_bindings.glsl).
#ifndef LF_TRACE_GLSL
#define LF_TRACE_GLSL

#include "buffer_bindings.glsl"
#ifndef LF_BVH_STACK_SIZE
#define LF_BVH_STACK_SIZE 48  // = kBvhMaxDepth in trace/bvh.h
#endif

// BvhNode (64 bytes): left box, right box; child index/count in the w's.
layout(std430, binding = LF_BINDING_BVH_NODES) readonly buffer LfBvhNodes { vec4 lf_bvh_nodes[]; };
// BvhTriangle (48 bytes): v0 (w = scene triangle index bits), v1, v2.
layout(std430, binding = LF_BINDING_BVH_TRIANGLES) readonly buffer LfBvhTriangles { vec4 lf_bvh_tris[]; };

const uint LF_NO_HIT = 0xffffffffu;

struct Hit {
    float t;
    uint triangle;  // scene triangle index, LF_NO_HIT on a miss
    vec2 bary;      // (b1, b2): weights of the triangle's 2nd and 3rd vertex
    bool front;     // the ray met the side the triangle's counter-clockwise normal faces
    vec3 normal;    // the triangle's geometric normal (counter-clockwise), not normalized
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
// On a hit with 0 < t < t_max, returns true and sets t and (b1, b2).
bool intersect_triangle(vec3 org, RayShear sh, vec3 v0, vec3 v1, vec3 v2, float t_max,
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
    if (!(t > 0.0 && t < t_max)) return false;
    bary = vec2(V, W) * inv_det;
    return true;
}

// Entry and exit distances of the ray with a box. An unused child slot holds
// a box at +infinity, which no ray enters (see build_bvh).
// The exit distance is pushed out by a few ulps (Ize 2013, "Robust BVH Ray
// Traversal") so rounding never drops a box whose face a ray grazes: a ray
// through a vertex on the box's surface must still reach the triangles.
bool intersect_box(vec3 org_x_inv, vec3 inv_dir, vec3 lo, vec3 hi, float t_max, out float t_enter) {
    vec3 t0 = lo * inv_dir - org_x_inv;
    vec3 t1 = hi * inv_dir - org_x_inv;
    vec3 tn = min(t0, t1), tf = max(t0, t1);
    t_enter = max(max(tn.x, tn.y), max(tn.z, 0.0));
    float t_exit = min(min(tf.x, tf.y), min(tf.z, t_max)) * 1.0000004;
    return t_enter <= t_exit;
}

vec3 safe_inverse(vec3 d) {
    const float tiny = 1e-30;
    return 1.0 / vec3(abs(d.x) > tiny ? d.x : (d.x < 0.0 ? -tiny : tiny),
                      abs(d.y) > tiny ? d.y : (d.y < 0.0 ? -tiny : tiny),
                      abs(d.z) > tiny ? d.z : (d.z < 0.0 ? -tiny : tiny));
}

// The traversal, shared by both queries. any_hit: stop at the first hit
// (occlusion). Returns the closest hit found below t_max.
Hit lf_traverse(vec3 org, vec3 dir, float t_max, bool any_hit) {
    Hit hit = Hit(t_max, LF_NO_HIT, vec2(0.0), false, vec3(0.0));
    RayShear sh = ray_shear(dir);
    vec3 inv_dir = safe_inverse(dir);
    vec3 org_x_inv = org * inv_dir;
    uint stack[LF_BVH_STACK_SIZE];
    int sp = 0;
    uint node = 0u;
    while (true) {
        vec4 n0 = lf_bvh_nodes[4u * node + 0u];
        vec4 n1 = lf_bvh_nodes[4u * node + 1u];
        vec4 n2 = lf_bvh_nodes[4u * node + 2u];
        vec4 n3 = lf_bvh_nodes[4u * node + 3u];
        uint child[2] = uint[2](floatBitsToUint(n0.w), floatBitsToUint(n1.w));
        uint count[2] = uint[2](floatBitsToUint(n2.w), floatBitsToUint(n3.w));
        float t_enter[2];
        bool enter[2];
        enter[0] = intersect_box(org_x_inv, inv_dir, n0.xyz, n1.xyz, hit.t, t_enter[0]);
        enter[1] = intersect_box(org_x_inv, inv_dir, n2.xyz, n3.xyz, hit.t, t_enter[1]);
        // Leaves are tested right away; only interior children are traversed.
        for (int c = 0; c < 2; ++c) {
            if (!enter[c] || count[c] == 0u) continue;
            enter[c] = false;
            for (uint i = child[c]; i < child[c] + count[c]; ++i) {
                float t; vec2 b;
                vec3 v0 = lf_bvh_tris[3u * i].xyz, v1 = lf_bvh_tris[3u * i + 1u].xyz, v2 = lf_bvh_tris[3u * i + 2u].xyz;
                if (intersect_triangle(org, sh, v0, v1, v2, hit.t, t, b)) {
                    vec3 ng = cross(v1 - v0, v2 - v0);
                    hit = Hit(t, floatBitsToUint(lf_bvh_tris[3u * i].w), b, dot(ng, dir) < 0.0, ng);
                    if (any_hit) return hit;
                }
            }
        }
        if (enter[0] && enter[1]) {
            bool left_first = t_enter[0] <= t_enter[1];
            stack[sp++] = left_first ? child[1] : child[0];
            node = left_first ? child[0] : child[1];
        } else if (enter[0]) {
            node = child[0];
        } else if (enter[1]) {
            node = child[1];
        } else {
            if (sp == 0) break;
            node = stack[--sp];
        }
    }
    return hit;
}

// Closest hit along org + t dir, 0 < t < t_max (dir need not be unit length;
// t is in units of |dir|).
Hit trace_closest(vec3 org, vec3 dir, float t_max) { return lf_traverse(org, dir, t_max, false); }

// True if anything lies along org + t dir, 0 < t < t_max.
bool trace_occluded(vec3 org, vec3 dir, float t_max) {
    return lf_traverse(org, dir, t_max, true).triangle != LF_NO_HIT;
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
