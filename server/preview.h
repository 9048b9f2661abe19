// What the status page shows of a lightmap (or, for a job without one, of
// its ambient occlusion: the first image output of the registry the job
// has, or ?output=NAME), made from its EXR (linear, rows from the top)
// without any GL:
//   GET /v1/jobs/{id}/preview.png        tone-mapped 8-bit sRGB, to look at as an atlas
//   GET /v1/jobs/{id}/lightmap.rgbm.png  RGBM (protocol/lightmap_rgbm.h), for the 3D view's lightMap
//   GET /v1/jobs/{id}/error.png          the per-texel relative error as a colour scale
#pragma once

#include <map>
#include <string>

namespace lf::server {

enum class PreviewKind { Tonemapped, Rgbm, Error };

struct Preview {
    std::string png;
    // Response headers that say how to read the image:
    // X-Lightfarm-Exposure (the automatic exposure, every kind),
    // X-Lightfarm-Rgbm-Range (Rgbm).
    std::map<std::string, std::string> headers;
};

// All three kinds from one read of the EXR (a page showing a pass asks for
// each of them); Error is absent when the file has no "error" channel.
// Exposure: the geometric mean luminance of the lit texels brought to 0.18
// (robust to the few very bright texels beside a light). Tonemapped applies
// it as every preview does (protocol/lightmap_preview.h: the preview.png a
// bake writes is the same image of its final lightmap).
// Error: relative standard error (the "error" channel over the texel's
// luminance) on a logarithmic scale from kErrorScaleLow (blue) to
// kErrorScaleHigh (red), texels without light black, texels with fewer than
// 2 samples (no variance yet) grey.
// Throws std::runtime_error naming the path.
std::map<PreviewKind, Preview> render_previews(const std::string& exr_path);

inline constexpr double kErrorScaleLow = 0.001;
inline constexpr double kErrorScaleHigh = 1.0;

}  // namespace lf::server
