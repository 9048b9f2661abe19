#include "preview.h"

#include <OpenEXR/ImfArray.h>
#include <OpenEXR/ImfRgbaFile.h>
#include <stb/stb_image_write.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace lf::server {

namespace {
unsigned char encode_srgb(float linear) {
    const float c = std::clamp(linear, 0.0f, 1.0f);
    const float s = c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
    return static_cast<unsigned char>(std::lround(s * 255.0f));
}

void append_bytes(void* context, void* data, int size) {
    static_cast<std::string*>(context)->append(static_cast<const char*>(data), size_t(size));
}
}  // namespace

std::string exr_to_png(const std::string& exr_path) {
    int width = 0, height = 0;
    Imf::Array2D<Imf::Rgba> pixels;
    try {
        Imf::RgbaInputFile file(exr_path.c_str());
        const Imath::Box2i dw = file.dataWindow();
        width = dw.max.x - dw.min.x + 1;
        height = dw.max.y - dw.min.y + 1;
        pixels.resizeErase(height, width);
        file.setFrameBuffer(&pixels[0][0] - dw.min.x - dw.min.y * width, 1, size_t(width));
        file.readPixels(dw.min.y, dw.max.y);
    } catch (const std::exception& e) {
        throw std::runtime_error("cannot read " + exr_path + ": " + e.what());
    }

    // Auto exposure from the geometric mean of lit texels: robust to a few
    // very bright ones (texels beside a light).
    double log_sum = 0;
    size_t lit = 0;
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            const Imf::Rgba& p = pixels[y][x];
            const float lum = 0.2126f * float(p.r) + 0.7152f * float(p.g) + 0.0722f * float(p.b);
            if (std::isfinite(lum) && lum > 1e-8f) {
                log_sum += std::log(double(lum));
                ++lit;
            }
        }
    const float exposure = lit ? float(0.18 / std::exp(log_sum / double(lit))) : 1.0f;

    std::vector<unsigned char> rgb(size_t(width) * size_t(height) * 3);
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            const Imf::Rgba& p = pixels[y][x];
            const float c[3] = {float(p.r), float(p.g), float(p.b)};
            for (int k = 0; k < 3; ++k) {
                float v = std::isfinite(c[k]) ? std::max(0.0f, c[k]) * exposure : 0.0f;
                v = v / (1.0f + v);
                rgb[(size_t(y) * size_t(width) + size_t(x)) * 3 + size_t(k)] = encode_srgb(v);
            }
        }
    std::string png;
    if (!stbi_write_png_to_func(append_bytes, &png, width, height, 3, rgb.data(), width * 3))
        throw std::runtime_error("cannot encode a PNG preview of " + exr_path);
    return png;
}

}  // namespace lf::server
