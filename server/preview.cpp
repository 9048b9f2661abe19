#include "preview.h"

#include "display_tone.h"
#include "lightmap_preview.h"
#include "lightmap_rgbm.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace lf::server {

namespace {

// R, G, B (and "error" when present) of an EXR, as floats, rows from the top.
struct LightmapPixels {
    int width = 0, height = 0;
    std::vector<float> rgb;      // 3 per pixel
    std::vector<float> error;    // empty when the file has no error channel
    std::vector<float> samples;  // empty when the file has no samples channel
};

LightmapPixels read_lightmap(const std::string& path) {
    LightmapPixels out;
    try {
        Imf::InputFile file(path.c_str());
        const Imath::Box2i dw = file.header().dataWindow();
        out.width = dw.max.x - dw.min.x + 1;
        out.height = dw.max.y - dw.min.y + 1;
        const size_t pixels = size_t(out.width) * size_t(out.height);
        out.rgb.assign(pixels * 3, 0.0f);
        const auto has = [&](const char* name) { return file.header().channels().findChannel(name) != nullptr; };
        if (has("error")) out.error.assign(pixels, 0.0f);
        if (has("samples")) out.samples.assign(pixels, 0.0f);
        const auto origin = [&](float* base, size_t stride) {
            return reinterpret_cast<char*>(base -
                                           (ptrdiff_t(dw.min.x) + ptrdiff_t(dw.min.y) * out.width) * ptrdiff_t(stride));
        };
        Imf::FrameBuffer frame;
        const char* names[3] = {"R", "G", "B"};
        for (int c = 0; c < 3; ++c)
            frame.insert(names[c], Imf::Slice(Imf::FLOAT, origin(out.rgb.data() + c, 3), 3 * sizeof(float),
                                              3 * sizeof(float) * size_t(out.width)));
        for (auto [name, data] : {std::pair{"error", &out.error}, std::pair{"samples", &out.samples}})
            if (!data->empty())
                frame.insert(name, Imf::Slice(Imf::FLOAT, origin(data->data(), 1), sizeof(float),
                                              sizeof(float) * size_t(out.width)));
        file.setFrameBuffer(frame);
        file.readPixels(dw.min.y, dw.max.y);
    } catch (const std::exception& e) {
        throw std::runtime_error("cannot read " + path + ": " + e.what());
    }
    return out;
}

float luminance(const float* rgb) { return 0.2126f * rgb[0] + 0.7152f * rgb[1] + 0.0722f * rgb[2]; }

std::string rgb_png(const std::vector<unsigned char>& rgb, int width, int height, const std::string& path) {
    try {
        return protocol::encode_png(rgb.data(), width, height, 3);
    } catch (const std::exception& e) {
        throw std::runtime_error("cannot encode a PNG preview of " + path + ": " + e.what());
    }
}

// Blue (low) through green and yellow to red (high): a scale read without a legend's help.
void error_colour(double t, unsigned char* rgb) {
    static const float stops[5][3] = {
        {0.1f, 0.2f, 0.9f}, {0.0f, 0.7f, 0.8f}, {0.2f, 0.8f, 0.2f}, {0.95f, 0.85f, 0.1f}, {0.9f, 0.1f, 0.1f}};
    const double x = std::clamp(t, 0.0, 1.0) * 4.0;
    const int i = std::min(3, int(x));
    const float f = float(x - i);
    for (int c = 0; c < 3; ++c) rgb[c] = protocol::encode_srgb8(stops[i][c] + (stops[i + 1][c] - stops[i][c]) * f);
}

constexpr unsigned char kUnknownGrey = 128;

std::vector<unsigned char> error_scale(const LightmapPixels& image) {
    std::vector<unsigned char> out(image.rgb.size(), 0);
    const double decades = std::log10(kErrorScaleHigh / kErrorScaleLow);
    for (size_t p = 0; p < image.error.size(); ++p) {
        const float lum = luminance(&image.rgb[3 * p]);
        if (!(lum > 1e-8f) || !std::isfinite(image.error[p])) continue;
        if (!image.samples.empty() && image.samples[p] < 2.0f) {  // not known yet (one sample has no variance)
            std::fill_n(&out[3 * p], 3, kUnknownGrey);
            continue;
        }
        const double relative = std::max(double(image.error[p]) / lum, kErrorScaleLow);
        error_colour(std::log10(relative / kErrorScaleLow) / decades, &out[3 * p]);
    }
    return out;
}

std::string number(double v) {
    char text[32];
    std::snprintf(text, sizeof text, "%.6g", v);
    return text;
}

}  // namespace

std::map<PreviewKind, Preview> render_previews(const std::string& exr_path) {
    const LightmapPixels image = read_lightmap(exr_path);
    const double exposure = protocol::automatic_exposure(image.rgb);
    std::map<PreviewKind, Preview> out;
    try {
        out[PreviewKind::Tonemapped].png =
            protocol::lightmap_preview_png(image.rgb, image.width, image.height, exposure);
    } catch (const std::exception& e) {
        throw std::runtime_error("cannot encode a PNG preview of " + exr_path + ": " + e.what());
    }
    const protocol::RgbmImage rgbm = protocol::encode_rgbm(image.rgb, image.width, image.height);
    out[PreviewKind::Rgbm].png = protocol::rgbm_png(rgbm);
    out[PreviewKind::Rgbm].headers["X-Lightfarm-Rgbm-Range"] = number(rgbm.range);
    if (!image.error.empty())
        out[PreviewKind::Error].png = rgb_png(error_scale(image), image.width, image.height, exr_path);
    for (auto& [kind, preview] : out) preview.headers["X-Lightfarm-Exposure"] = number(exposure);
    return out;
}

}  // namespace lf::server
