// The small numeric helpers that several parts of gi use: one definition each.
#pragma once

#include <glm/glm.hpp>

namespace lf {

inline constexpr double kPi = 3.14159265358979323846;

// The z of the cross product of two 2D vectors: twice the signed area of the
// triangle they span, positive when b lies counter-clockwise of a.
inline double cross2(glm::dvec2 a, glm::dvec2 b) { return a.x * b.y - a.y * b.x; }

// One number for a colour (an emitter's power, an albedo): its channels' mean.
inline float channel_mean(glm::vec3 c) { return (c.r + c.g + c.b) / 3.0f; }

}  // namespace lf
