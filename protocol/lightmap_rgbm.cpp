#include "lightmap_rgbm.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace lf::protocol {

namespace {
float storable(float v) { return std::isfinite(v) && v > 0.0f ? v : 0.0f; }
}  // namespace

RgbmImage encode_rgbm(const std::vector<float>& rgb, int width, int height) {
    const size_t pixels = size_t(std::max(width, 0)) * size_t(std::max(height, 0));
    if (rgb.size() != pixels * 3)
        throw std::invalid_argument("encode_rgbm: " + std::to_string(rgb.size()) + " values for " +
                                    std::to_string(width) + "x" + std::to_string(height) + " RGB pixels");
    RgbmImage out;
    out.width = width;
    out.height = height;
    float brightest = 0;
    for (float v : rgb) brightest = std::max(brightest, storable(v));
    out.range = brightest > 0 ? brightest : 1.0f;
    out.rgba.resize(pixels * 4);
    for (size_t p = 0; p < pixels; ++p) {
        const float c[3] = {storable(rgb[3 * p]), storable(rgb[3 * p + 1]), storable(rgb[3 * p + 2])};
        const float largest = std::max({c[0], c[1], c[2]}) / out.range;
        // The multiplier rounded up to the next 8-bit step, so rgb = c / (range * m) <= 1.
        const int m = std::clamp(int(std::ceil(largest * 255.0f)), 1, 255);
        const float scale = 255.0f / (out.range * float(m) / 255.0f);
        for (int k = 0; k < 3; ++k) out.rgba[4 * p + size_t(k)] = uint8_t(std::min(255.0f, std::round(c[k] * scale)));
        out.rgba[4 * p + 3] = uint8_t(m);
    }
    return out;
}

std::vector<float> decode_rgbm(const RgbmImage& image) {
    std::vector<float> rgb(image.rgba.size() / 4 * 3);
    for (size_t p = 0; p < image.rgba.size() / 4; ++p) {
        const float m = float(image.rgba[4 * p + 3]) / 255.0f;
        for (int k = 0; k < 3; ++k)
            rgb[3 * p + size_t(k)] = image.range * float(image.rgba[4 * p + size_t(k)]) / 255.0f * m;
    }
    return rgb;
}

std::string rgbm_png(const RgbmImage& image, const PngStripRunner& run) {
    if (image.rgba.size() != size_t(std::max(image.width, 0)) * size_t(std::max(image.height, 0)) * 4)
        throw std::invalid_argument("rgbm_png: " + std::to_string(image.rgba.size()) + " bytes for " +
                                    std::to_string(image.width) + "x" + std::to_string(image.height) + " RGBA pixels");
    return encode_png(image.rgba.data(), image.width, image.height, 4, run);
}

}  // namespace lf::protocol
