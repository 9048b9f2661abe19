// `--denoise`: an edge-aware filter of the lightmap on the GPU
// (gi/shaders/lightmap_denoise.comp: the à-trous wavelet of Dammertz et al.
// 2010 with SVGF's variance guidance, each step a weighted plane fit rather
// than a mean), guided by the texels' positions, normals and charts, never
// across a chart's border. Whether it is worth its
// bias is measured, not assumed: docs/BENCHMARKS.md "Denoising".
#pragma once

#include "atlas/texel_samples.h"
#include "gpu/shader.h"
#include "io/image_files.h"
#include "scene/scene.h"

namespace lf {

class LightmapDenoiser {
public:
    static constexpr int kSteps = 5;  // step sizes 1, 2, 4, 8, 16

    // The guide (position, chart, normal, world size of every covered texel)
    // goes to the GPU once. Needs a current GL context.
    LightmapDenoiser(const Scene& atlas_scene, const TexelSamples& texels);

    // Filters `image`'s RGB (the combined lightmap), guided by its "error"
    // channel (the standard error of each texel's estimate), and keeps the
    // unfiltered RGB as layer "raw." (raw.R, raw.G, raw.B). Each chart keeps
    // its raw light: its filtered texels are scaled, channel by channel, to
    // the raw texels' sum (conserve_chart_light). The direct and
    // indirect layers stay as baked. Dilated texels copy their filtered
    // source again. Its time (upload, filter, read back) goes into the
    // header attribute lightfarm.denoiseSeconds.
    void denoise(FloatImage& image) const;

private:
    const TexelSamples& texels_;
    std::vector<uint32_t> texel_chart_;  // per covered texel: its chart (the guide's)
    ComputeProgram program_;
    GpuBuffer guide_;
};

}  // namespace lf
