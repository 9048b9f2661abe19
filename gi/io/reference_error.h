// Error of a lightmap against a reference (DESIGN.md "Conventions"): RMSE over
// the covered texels and the three channels, relative to the reference's mean
// there; bias = mean / reference mean - 1. The same definition as the Cycles
// reference figures in examples/SOURCES.md, so numbers compare directly.
#pragma once

#include "io/image_files.h"

namespace lf {

struct ReferenceError {
    double rmse = 0.0;
    double relative_rmse = 0.0;
    double bias = 0.0;  // mean / reference mean - 1
    double reference_mean = 0.0;
    size_t texels = 0;  // texels compared
    // Where the error sits, texel by texel (whatever the block size): the
    // share of the squared error that the worst 2% of the texels carry, and
    // the texels at least twice as bright as the reference (or under half
    // of it) by more than noise explains: 3 x (the bake's + the reference's
    // "error" channel, where they have one) + a tenth of the reference's
    // mean. Strips and lines of wrong texels (light through a wall's foot)
    // show here; noise does not.
    double worst_2_percent_share = 0.0;
    size_t twice_too_bright = 0;
    size_t half_too_dark = 0;
    double outlier_share = 0.0;  // of the squared error, in those texels
};

// The channel a baked lightmap marks its surface texels with: 1 on covered
// texels, 0 on the dilated ring around each chart (copies of the chart's
// border texels, there for bilinear lookups) and on empty atlas space.
constexpr const char* kCoveredChannel = "covered";

// `mask`: texels with a first channel > 0.5 are compared. Without one, the
// bake's kCoveredChannel where it has one: each surface texel counts once.
// (Counting every texel whose reference is non-zero, as files without that
// channel still are, counts a chart's border texels once more for each ring
// texel that copies them: a one-texel chart 49 times. On grey_white_room at
// 654², with thousands of small charts, that turned a bias of +0.01% into
// -1.7%.) A reference (and mask) k times larger
// than the bake in both directions is box-filtered down first, a texel
// counting only when all k² texels under it are in the mask: the same atlas
// baked at 64² compares with a 256² reference.
// Box-filters `image` by an integer factor; a channel "Y" or the first
// channel of a mask image keeps 1 only where every source texel was > 0.5.
FloatImage downsample(const FloatImage& image, int factor, bool is_mask);
// `block` > 1: the means of block x block squares of texels (each over the
// texels compared in it) are compared instead of the texels, each counted
// once per texel it holds: the low-frequency part of the error (blotches a
// filter leaves or makes), with the reference's own noise averaged over the
// block. The bias is the same at every block size.
ReferenceError compare_to_reference(const FloatImage& bake, const FloatImage& reference, const FloatImage* mask,
                                    int block = 1);

}  // namespace lf
