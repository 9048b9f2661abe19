// RGBM: the 8-bit HDR encoding a lightmap leaves the service in for viewers —
// the image scene.lit.glb embeds and GET /v1/jobs/{id}/lightmap.rgbm.png.
// Both sides use it (the engine writes the glb, the server the live view),
// so it is defined once, here.
//
//   value = range * (r, g, b) * a     r, g, b, a in [0, 1], 8 bits each, linear (not sRGB)
//
// `range` is the largest value in the image, recorded beside the image (the
// glb's MOZ_lightmap extras, the server's X-Lightfarm-Rgbm-Range header). The
// multiplier a is rounded up so that r, g, b <= 1, and each value comes back
// within half a step of range * a / 255². So a pixel's brightest channel keeps
// 0.4% from range / 255 up (its byte is at least 127), and below that an
// absolute step of range / 255²: the dynamic range is 65,025:1, where plain
// 8 bits have 255:1.
#pragma once

#include "png.h"

#include <cstdint>
#include <string>
#include <vector>

namespace lf::protocol {

struct RgbmImage {
    int width = 0;
    int height = 0;
    float range = 1;            // value = range * rgb * a
    std::vector<uint8_t> rgba;  // width * height * 4, rows from the top
};

// `rgb` holds width * height * 3 linear values, rows from the top. Negative
// and non-finite values are stored as 0.
RgbmImage encode_rgbm(const std::vector<float>& rgb, int width, int height);

// The linear RGB values an RgbmImage stands for (width * height * 3).
std::vector<float> decode_rgbm(const RgbmImage& image);

// The image as a PNG file (RGBA, 8 bits; encode_png, its strips run by
// `run`). Throws std::invalid_argument for an empty image.
std::string rgbm_png(const RgbmImage& image, const PngStripRunner& run = {});

}  // namespace lf::protocol
