// Sampling directions and points. Shared by every method.
#ifndef LF_SAMPLING_GLSL
#define LF_SAMPLING_GLSL

const float PI = 3.14159265358979;

// An orthonormal basis around unit n (Duff et al. 2017, "Building an
// Orthonormal Basis, Revisited"): no branches on the normal's direction.
void orthonormal_basis(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

// Cosine-distributed direction about n from u in [0,1)^2; pdf = cos / pi.
// Malley's method: uniform on the disk (concentric map), lifted to the hemisphere.
vec3 sample_cosine_hemisphere(vec3 n, vec2 u) {
    vec2 d = 2.0 * u - 1.0;
    float r, phi;
    if (d.x == 0.0 && d.y == 0.0) { r = 0.0; phi = 0.0; }
    else if (abs(d.x) > abs(d.y)) { r = d.x; phi = (PI / 4.0) * (d.y / d.x); }
    else { r = d.y; phi = (PI / 2.0) - (PI / 4.0) * (d.x / d.y); }
    vec2 disk = r * vec2(cos(phi), sin(phi));
    float z = sqrt(max(0.0, 1.0 - dot(disk, disk)));
    vec3 t, b;
    orthonormal_basis(n, t, b);
    return normalize(disk.x * t + disk.y * b + z * n);
}

// Low-discrepancy sequences for samples taken one per pass: R2 and R3
// (Roberts 2018), the additive recurrences by the inverse powers of the
// plastic number 1.3247179572... (x^3 = x + 1) and of 1.2207440846...
// (x^4 = x + 1), shifted by a per-texel `rotation` (Cranley-Patterson). In
// 0.32 fixed point, where the wrap-around of unsigned arithmetic is the
// fract(), so the millionth point is as exact as the first (a float
// `fract(rotation + n * alpha)` keeps fewer bits of it as n grows). A
// coordinate that picks something discrete (an emitter) stays stratified
// jointly with the continuous ones.
vec2 r2_sample(uvec2 rotation, uint n) {
    const uvec2 alpha = uvec2(3242174889u, 2447445414u);  // 2^32 x (0.7548776662, 0.5698402910)
    return vec2((rotation + n * alpha) >> 8u) * (1.0 / 16777216.0);
}

vec3 r3_sample(uvec3 rotation, uint n) {
    const uvec3 alpha = uvec3(3518319155u, 2882110345u, 2360945575u);  // 1.2207440846...
    return vec3((rotation + n * alpha) >> 8u) * (1.0 / 16777216.0);
}

// Uniform barycentrics (b1, b2) on a triangle from u in [0,1)^2.
vec2 sample_triangle(vec2 u) {
    float s = sqrt(u.x);
    return vec2(1.0 - s, u.y * s);
}

// Barycentrics (b1, b2) of a point p in the plane of triangle (a, b, c):
// p = (1 - b1 - b2) a + b1 b + b2 c.
vec2 triangle_barycentrics(vec3 p, vec3 a, vec3 b, vec3 c) {
    vec3 e1 = b - a, e2 = c - a, d = p - a;
    float d11 = dot(e1, e1), d12 = dot(e1, e2), d22 = dot(e2, e2);
    float d1 = dot(d, e1), d2 = dot(d, e2);
    float det = d11 * d22 - d12 * d12;
    if (det <= 0.0) return vec2(1.0 / 3.0);
    return clamp(vec2(d22 * d1 - d12 * d2, d11 * d2 - d12 * d1) / det, 0.0, 1.0);
}

// atan2 to float precision. GLSL leaves the precision of atan to the
// implementation: llvmpipe's is off by up to 2e-6 rad, which is 1e-4 of a
// solid angle of 0.02 sr (the Cornell box's light from its floor), and so
// a bias of 1e-4 in every light sample. One Newton step on
// f(t) = y cos t - x sin t squares the error, given sin and cos that are
// accurate (1.7e-7 rad measured).
float accurate_atan2(float y, float x) {
    float t = atan(y, x);
    float s = sin(t), c = cos(t);
    return t + (y * c - x * s) / (x * c + y * s);
}

// The triangle (A, B, C) as seen from x, and its solid angle (Van Oosterom and
// Strackee 1983: tan(omega / 2) = |a . (b x c)| / (1 + a.b + b.c + c.a) for
// unit a, b, c), which has no cancellation. The spherical excess
// alpha + beta + gamma - pi, from three acos, loses the solid angle of a
// small triangle to their rounding: on llvmpipe the Cornell box's light
// (0.015 sr from its floor) came out 1-2% off, texel by texel, and so did
// its direct light (tests/test_radiosity.cpp, SphericalTriangles).
// 0 when too degenerate or under 0.001 sr, where the float sampler below
// drifts from uniform (1% at 3e-4 sr: its cosines of small arcs round off)
// while sampling by area is nearly as good; callers then sample by area,
// and sampler and density use this one test, so they always agree.
struct SphericalTriangle {
    vec3 a, b, c;  // unit directions from x to the corners
    float area;    // the solid angle; 0: sample the triangle by area instead
};

SphericalTriangle spherical_triangle(vec3 x, vec3 A, vec3 B, vec3 C) {
    SphericalTriangle t;
    t.a = normalize(A - x), t.b = normalize(B - x), t.c = normalize(C - x);
    vec3 n_ab = cross(t.a, t.b), n_bc = cross(t.b, t.c), n_ca = cross(t.c, t.a);
    t.area = 0.0;
    if (dot(n_ab, n_ab) < 1e-12 || dot(n_bc, n_bc) < 1e-12 || dot(n_ca, n_ca) < 1e-12) return t;
    float area = 2.0 * accurate_atan2(abs(dot(t.a, n_bc)), 1.0 + dot(t.a, t.b) + dot(t.b, t.c) + dot(t.c, t.a));
    t.area = area > 1e-3 ? area : 0.0;
    return t;
}

// A direction uniform in solid angle within spherical triangle `seen`, whose
// area is > 0 (Arvo 1995, "Stratified Sampling of Spherical Triangles").
// The angle alpha at a comes from accurate_atan2 for the same reason as the
// solid angle: the sub-triangle of solid angle u.x * area is only that if
// alpha is exact.
vec3 sample_spherical_triangle(SphericalTriangle seen, vec2 u) {
    vec3 a = seen.a, b = seen.b, c = seen.c;
    float area = seen.area;
    vec3 n_ab = normalize(cross(a, b)), n_ca = normalize(cross(c, a));
    float cos_alpha = -dot(n_ab, n_ca), sin_alpha = length(cross(n_ab, n_ca));
    float alpha = accurate_atan2(sin_alpha, cos_alpha);
    // The sub-triangle of solid angle u.x * area: its third vertex c_hat on the arc a..c.
    float area_hat = u.x * area;
    float s = sin(area_hat - alpha), t = cos(area_hat - alpha);
    float cos_c = dot(a, b);
    float uu = t - cos_alpha, vv = s + sin_alpha * cos_c;
    float q = clamp(((vv * t - uu * s) * cos_alpha - vv) / ((vv * s + uu * t) * sin_alpha), -1.0, 1.0);
    vec3 c_hat = q * a + sqrt(max(0.0, 1.0 - q * q)) * normalize(c - dot(c, a) * a);
    // Then uniformly in z = cos along the arc from b to c_hat.
    float z = 1.0 - u.y * (1.0 - dot(c_hat, b));
    vec3 perp = c_hat - dot(c_hat, b) * b;
    if (dot(perp, perp) < 1e-14) return b;
    return normalize(z * b + sqrt(max(0.0, 1.0 - z * z)) * normalize(perp));
}

#endif
