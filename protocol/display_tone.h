// How lightfarm puts light on a screen, defined once for every view of a
// bake: the server's previews and live view, the status page's 3D view
// (web/ui/status-view3d.js mirrors it), and scene.unlit.glb, whose texture
// holds what that view shows.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

namespace lf::protocol {

// The exposure that maps the geometric mean luminance of the lit values
// (Rec. 709 luminance above 1e-8 and above kExposureFloor of the brightest)
// to middle grey 0.18, Reinhard et al.'s "key" (2002); 1 when nothing is
// lit. `rgb`: interleaved linear RGB.
double automatic_exposure(const std::vector<float>& rgb);

// Texels darker than this fraction of the brightest do not count towards
// the exposure: an RGBM texel's smallest step is 1/65025 of its range, so a
// viewer that reads the lightmap from scene.lit.glb sees them as black or
// far off (a denoised map spreads a little light into texels whose paths
// found none: 6% of the Cornell box's exposure at 96², 32 passes, counted in
// the file and not in the view).
constexpr float kExposureFloor = 1e-4f;

// The filmic curve the 3D view renders with: three.js's
// ACESFilmicToneMapping (r171), Stephen Hill's fit of the ACES reference
// rendering and output transforms, with its exposure / 0.6. Linear scene
// radiance in, linear display values in [0, 1] out.
std::array<float, 3> aces_filmic(std::array<float, 3> linear, float exposure);

// The sRGB transfer function (IEC 61966-2-1) to 8 bits, clamped to [0, 1].
uint8_t encode_srgb8(float linear);

}  // namespace lf::protocol
