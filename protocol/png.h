// PNG files of 8-bit pixels, written with zlib: each row Paeth-filtered
// (PNG filter 4: lightmaps and previews are smooth), the rows compressed in
// strips of kPngStripRows, each strip a run of deflate blocks of its own
// (the next starts after a full flush, so strips are compressed side by
// side, as pigz does). The bytes depend on the pixels alone, not on how
// the strips were run. A 1024² RGBM lightmap: 0.18 s on one core, 0.08 s
// on two, and 17% fewer bytes, where stb_image_write took 0.30 s
// (docs/BENCHMARKS.md, "The final files").
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>

namespace lf::protocol {

inline constexpr int kPngStripRows = 64;

// Runs strip(i) for every i in [0, count), in any order and on any threads;
// returns when all have run. Empty: one after another on this thread.
using PngStripRunner = std::function<void(size_t count, const std::function<void(size_t)>& strip)>;

// `pixels`: height rows of width x channels bytes, top row first;
// channels 3 (RGB) or 4 (RGBA). Throws std::invalid_argument for an empty
// image or another channel count.
std::string encode_png(const uint8_t* pixels, int width, int height, int channels, const PngStripRunner& run = {});

}  // namespace lf::protocol
