// A lightmap to look at as an atlas, one rule for every place that shows
// it: the service's GET /v1/jobs/{id}/preview.png (server/preview.h) and
// the preview.png a bake writes beside lightmap.exr (the CLI's and the
// worker's alike).
#pragma once

#include <string>
#include <vector>

namespace lf::protocol {

// `rgb`: linear irradiance/pi, interleaved, rows from the top. At
// `exposure` (automatic_exposure, display_tone.h), Reinhard x / (1 + x),
// the sRGB curve, 8 bits: a PNG's bytes. Unlit (and non-finite) texels are
// black. Throws std::runtime_error when the size does not match.
std::string lightmap_preview_png(const std::vector<float>& rgb, int width, int height, double exposure);

}  // namespace lf::protocol
