// Form factors in closed form, for the tests that check direct light
// against them (lightmaps, SH transfer, probes).
#pragma once

#include <cmath>
#include <initializer_list>

namespace lf::test {

// Irradiance/pi at a point on a plane from a parallel rectangle of radiance 1
// whose corner lies straight above it at height c, sides a, b: the
// differential-area-to-rectangle form factor (Howell's catalogue, C-11).
inline double corner_form_factor(double a, double b, double c) {
    const double x = a / c, y = b / c;
    const double sx = std::sqrt(1 + x * x), sy = std::sqrt(1 + y * y);
    return (x / sx * std::atan(y / sx) + y / sy * std::atan(x / sy)) / (2.0 * M_PI);
}

// Any point under a rectangle [x0,x1]x[z0,z1] at height h, by splitting it at the point.
inline double rectangle_form_factor(double px, double pz, double x0, double x1, double z0, double z1, double h) {
    // Signed rectangles from the point to each corner: F = F(x1,z1) - F(x0,z1) - F(x1,z0) + F(x0,z0).
    auto part = [&](double a, double b) {
        return (a == 0.0 || b == 0.0) ? 0.0 : corner_form_factor(std::abs(a), std::abs(b), h);
    };
    auto sgn = [](double v) { return v < 0 ? -1.0 : 1.0; };
    double f = 0.0;
    for (double xe : {x0, x1})
        for (double ze : {z0, z1}) {
            const double a = xe - px, b = ze - pz;
            const double s = sgn(a) * sgn(b) * (xe == x0 ? -1.0 : 1.0) * (ze == z0 ? -1.0 : 1.0);
            f += s * part(a, b);
        }
    return f;
}

}  // namespace lf::test
