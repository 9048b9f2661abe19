#include "trace/ray_reference.h"

#include <cmath>
#include <cstring>

namespace lf {

bool intersect_triangle_reference(const glm::vec3& org, const glm::vec3& dir, const glm::vec3& v0, const glm::vec3& v1,
                                  const glm::vec3& v2, float t_max, float* t, glm::vec2* bary) {
    const glm::vec3 a = glm::abs(dir);
    int kz = (a.x > a.y) ? ((a.x > a.z) ? 0 : 2) : ((a.y > a.z) ? 1 : 2);
    int kx = (kz + 1) % 3, ky = (kx + 1) % 3;
    if (dir[kz] < 0.0f) std::swap(kx, ky);
    const float sx = dir[kx] / dir[kz], sy = dir[ky] / dir[kz], sz = 1.0f / dir[kz];
    const glm::vec3 A = v0 - org, B = v1 - org, C = v2 - org;
    const float Ax = A[kx] - sx * A[kz], Ay = A[ky] - sy * A[kz];
    const float Bx = B[kx] - sx * B[kz], By = B[ky] - sy * B[kz];
    const float Cx = C[kx] - sx * C[kz], Cy = C[ky] - sy * C[kz];
    const float U = Cx * By - Cy * Bx, V = Ax * Cy - Ay * Cx, W = Bx * Ay - By * Ax;
    if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f)) return false;
    const float det = U + V + W;
    if (det == 0.0f) return false;
    const float T = U * (sz * A[kz]) + V * (sz * B[kz]) + W * (sz * C[kz]);
    const float inv_det = 1.0f / det;
    const float hit_t = T * inv_det;
    if (!(hit_t > 0.0f && hit_t < t_max)) return false;
    *t = hit_t;
    *bary = glm::vec2(V, W) * inv_det;
    return true;
}

RayHit trace_brute_force(const Scene& scene, const Ray& ray) {
    RayHit hit;
    hit.t = ray.t_max;
    for (size_t i = 0; i < scene.triangles.size(); ++i) {
        const glm::uvec3 tri = scene.triangles[i];
        float t;
        glm::vec2 b;
        if (intersect_triangle_reference(ray.origin, ray.direction, scene.positions[tri[0]], scene.positions[tri[1]],
                                         scene.positions[tri[2]], hit.t, &t, &b)) {
            hit = RayHit{t, uint32_t(i), b};
        }
    }
    return hit;
}

glm::vec3 offset_ray_origin(const glm::vec3& p, const glm::vec3& n) {
    constexpr float origin = 1.0f / 32.0f, float_scale = 1.0f / 65536.0f, int_scale = 256.0f;
    glm::vec3 out;
    for (int k = 0; k < 3; ++k) {
        const int of_i = int(int_scale * n[k]);
        int bits;
        std::memcpy(&bits, &p[k], sizeof bits);
        bits += p[k] < 0.0f ? -of_i : of_i;
        float p_i;
        std::memcpy(&p_i, &bits, sizeof p_i);
        out[k] = std::fabs(p[k]) < origin ? p[k] + float_scale * n[k] : p_i;
    }
    return out;
}

}  // namespace lf
