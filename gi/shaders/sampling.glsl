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

#endif
