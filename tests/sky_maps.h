// Environment maps with closed-form irradiance, shared by the tests of every
// output that an environment lights (the lightmap, the probes).
#pragma once

#include "sh/environment.h"

#include <glm/glm.hpp>

#include <algorithm>
#include <cmath>
#include <cstddef>

namespace lf::test {

// Radiance linear in the direction, L(ω) = c0 + c·ω per channel. Over the
// hemisphere of a normal n, E = ∫ (c0 + c·ω)(n·ω) dω = π c0 + (2π/3) c·n,
// so E/π = c0 + (2/3) c·n at every angle.
struct LinearSky {
    glm::dvec3 c0{1.0, 0.8, 0.6};
    glm::dmat3 c{glm::dvec3(0.3, 0.0, -0.2), glm::dvec3(0.5, -0.4, 0.1),
                 glm::dvec3(0.0, 0.3, -0.3)};  // columns: the coefficients of x, y, z (RGB each)

    Environment map(int width, int height) const {
        return environment_from_function(
            width, height, [this](glm::vec3 d) { return glm::vec3(c0 + c * glm::dvec3(d)); }, "linear test sky");
    }
    glm::dvec3 irradiance_over_pi(glm::dvec3 n) const { return c0 + (2.0 / 3.0) * (c * n); }
};

// A sky with a sun: a 256 x 128 map of 0.05 everywhere but a 2 x 2-texel
// sun of 2,500, its rows θ 39.4°–42.2° from the zenith, which gives 95% of
// what a plane facing up receives (E/π 0.998). The sky's part of E/π over a
// hemisphere is exactly 0.05; the sun's is integrated over its texels
// subdivided 64 x 64.
struct SunSky {
    static constexpr int width = 256, height = 128, sun_x = 100, sun_y = 28;
    static constexpr float sky = 0.05f, sun = 2500.0f;

    Environment map() const {
        Environment e;
        e.width = width;
        e.height = height;
        e.source = "a sky with a sun";
        e.texels.assign(size_t(width) * height, glm::vec3(sky));
        for (int y = sun_y; y < sun_y + 2; ++y)
            for (int x = sun_x; x < sun_x + 2; ++x) e.texels[size_t(y) * width + size_t(x)] = glm::vec3(sun);
        return e;
    }
    // The horizontal direction towards the sun's centre.
    glm::dvec3 towards_sun() const {
        const double phi = (sun_x + 1.0) / width * 2.0 * M_PI - M_PI;
        return {std::cos(phi), 0.0, std::sin(phi)};
    }
    double irradiance_over_pi(glm::dvec3 n) const {
        double sum = 0.0;
        const int k = 64;
        for (int y = sun_y; y < sun_y + 2; ++y)
            for (int x = sun_x; x < sun_x + 2; ++x)
                for (int j = 0; j < k; ++j)
                    for (int i = 0; i < k; ++i) {
                        const double theta = (y + (j + 0.5) / k) / height * M_PI;
                        const double phi = ((x + (i + 0.5) / k) / width - 0.5) * 2.0 * M_PI;
                        const glm::dvec3 w(std::sin(theta) * std::cos(phi), std::cos(theta),
                                           std::sin(theta) * std::sin(phi));
                        const double d_omega = (2.0 * M_PI / width / k) * (M_PI / height / k) * std::sin(theta);
                        sum += double(sun - sky) * std::max(0.0, glm::dot(n, w)) * d_omega;
                    }
        return sky + sum / M_PI;
    }
};

}  // namespace lf::test
