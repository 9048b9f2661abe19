#include "lightmap_preview.h"

#include "display_tone.h"
#include "png.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace lf::protocol {

std::string lightmap_preview_png(const std::vector<float>& rgb, int width, int height, double exposure) {
    if (width <= 0 || height <= 0 || rgb.size() != size_t(width) * size_t(height) * 3)
        throw std::runtime_error("a lightmap preview of " + std::to_string(width) + " x " + std::to_string(height) +
                                 " texels needs 3 values a texel, got " + std::to_string(rgb.size()));
    std::vector<unsigned char> shown(rgb.size());
    for (size_t i = 0; i < rgb.size(); ++i) {
        const float v = std::isfinite(rgb[i]) ? std::max(0.0f, rgb[i]) * float(exposure) : 0.0f;
        shown[i] = encode_srgb8(v / (1.0f + v));
    }
    return encode_png(shown.data(), width, height, 3);
}

}  // namespace lf::protocol
