#include "display_tone.h"

#include <algorithm>
#include <cmath>

namespace lf::protocol {

double automatic_exposure(const std::vector<float>& rgb) {
    auto luminance = [&](size_t p) { return 0.2126f * rgb[p] + 0.7152f * rgb[p + 1] + 0.0722f * rgb[p + 2]; };
    float brightest = 0.0f;
    for (size_t p = 0; p + 2 < rgb.size(); p += 3)
        if (std::isfinite(luminance(p))) brightest = std::max(brightest, luminance(p));
    const float least = std::max(1e-8f, kExposureFloor * brightest);
    double log_sum = 0;
    size_t lit = 0;
    for (size_t p = 0; p + 2 < rgb.size(); p += 3) {
        const float l = luminance(p);
        if (std::isfinite(l) && l > least) {
            log_sum += std::log(double(l));
            ++lit;
        }
    }
    return lit ? 0.18 / std::exp(log_sum / double(lit)) : 1.0;
}

std::array<float, 3> aces_filmic(std::array<float, 3> c, float exposure) {
    for (float& v : c) v = (std::isfinite(v) ? std::max(v, 0.0f) : 0.0f) * exposure / 0.6f;
    // sRGB to the rendering space with the RRT's saturation (rows here; three.js writes the transposes).
    const std::array<float, 3> in = {0.59719f * c[0] + 0.35458f * c[1] + 0.04823f * c[2],
                                     0.07600f * c[0] + 0.90834f * c[1] + 0.01566f * c[2],
                                     0.02840f * c[0] + 0.13383f * c[1] + 0.83777f * c[2]};
    std::array<float, 3> fit{};
    for (int i = 0; i < 3; ++i) {  // the RRT and ODT, fitted
        const float v = in[size_t(i)];
        fit[size_t(i)] = (v * (v + 0.0245786f) - 0.000090537f) / (v * (0.983729f * v + 0.4329510f) + 0.238081f);
    }
    // Back to sRGB with the ODT's saturation.
    const std::array<float, 3> out = {1.60475f * fit[0] - 0.53108f * fit[1] - 0.07367f * fit[2],
                                      -0.10208f * fit[0] + 1.10813f * fit[1] - 0.00605f * fit[2],
                                      -0.00327f * fit[0] - 0.07276f * fit[1] + 1.07602f * fit[2]};
    return {std::clamp(out[0], 0.0f, 1.0f), std::clamp(out[1], 0.0f, 1.0f), std::clamp(out[2], 0.0f, 1.0f)};
}

uint8_t encode_srgb8(float linear) {
    const float c = std::isfinite(linear) ? std::clamp(linear, 0.0f, 1.0f) : 0.0f;
    const float s = c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
    return uint8_t(std::lround(s * 255.0f));
}

}  // namespace lf::protocol
