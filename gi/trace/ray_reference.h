// A CPU reference for the GPU tracer: the same watertight ray/triangle test,
// over every triangle (no BVH), so any traversal bug shows as a difference.
#pragma once

#include "scene/scene.h"
#include "trace/tracer.h"

namespace lf {

// Watertight ray/triangle test (Woop, Benthin & Wald 2013), as in trace.glsl.
bool intersect_triangle_reference(const glm::vec3& org, const glm::vec3& dir, const glm::vec3& v0, const glm::vec3& v1,
                                  const glm::vec3& v2, float t_max, float* t, glm::vec2* bary);

// Closest hit over all triangles by brute force.
RayHit trace_brute_force(const Scene& scene, const Ray& ray);

// The origin offset of trace.glsl's offset_ray_origin, on the CPU.
glm::vec3 offset_ray_origin(const glm::vec3& p, const glm::vec3& n);

}  // namespace lf
