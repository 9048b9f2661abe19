// GET /v1/jobs/{id}/preview.png: an EXR (linear radiance) tone-mapped to an
// 8-bit sRGB PNG a person can look at.
#pragma once

#include <string>

namespace lf::server {

// Reads RGB of `exr_path`, scales by an automatic exposure (mean luminance
// of the lit texels to 0.18), applies Reinhard x/(1+x) and the sRGB curve.
// Unlit (black) texels stay black. Throws std::runtime_error with the path.
std::string exr_to_png(const std::string& exr_path);

}  // namespace lf::server
