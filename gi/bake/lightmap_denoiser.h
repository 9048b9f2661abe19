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

#include <glm/glm.hpp>

#include <vector>

namespace lf {

class LightmapDenoiser {
public:
    static constexpr int kSteps = 5;         // step sizes 1, 2, 4, 8, 16
    static constexpr int kRestoreSteps = 2;  // the low-frequency restore's low-pass: steps 1, 2 (13x13 texels)

    // The guide (position, chart, normal, world size of every covered texel)
    // goes to the GPU once. Needs a current GL context.
    LightmapDenoiser(const Scene& atlas_scene, const TexelSamples& texels);

    // Filters `image`'s RGB (the combined lightmap), guided by its "error"
    // channel (the standard error of each texel's estimate), its "lit"
    // channel and its lightfarm.pass attribute (sure_darks), and keeps the
    // unfiltered RGB as layer "raw." (raw.R, raw.G, raw.B). The low
    // frequencies of what the filter took are put back where they are more
    // than noise (restore_low_frequencies). Each chart keeps
    // its raw light: its filtered texels are scaled, channel by channel, to
    // the raw texels' sum (conserve_chart_light). The direct and
    // indirect layers stay as baked. Dilated texels copy their filtered
    // source again. Its time (upload, filter, read back) goes into the
    // header attribute lightfarm.denoiseSeconds.
    void denoise(FloatImage& image) const;

private:
    // `steps` à-trous steps of lightmap_denoise.comp over `colour` (rgb,
    // variance per atlas texel); with luminance weights, the texels `keep`
    // marks (a uint per atlas texel, 1: keep; sure_darks') stay as they are.
    std::vector<glm::vec4> filter(const std::vector<glm::vec4>& colour, int steps, bool luminance_weights,
                                  const GpuBuffer& keep) const;
    // Per atlas texel, 1 where the bake is sure of a 0 that its lit
    // neighbours would otherwise lend light to.
    std::vector<uint32_t> sure_darks(const FloatImage& image) const;
    // Adds back to `filtered` the low frequencies of what the filter took
    // from `raw` where they are more than noise (Wiener shrinkage); `keep`
    // is filter's, bound for the low-pass, which does not read it.
    void restore_low_frequencies(std::vector<glm::vec4>& filtered, const std::vector<glm::vec4>& raw,
                                 const GpuBuffer& keep) const;

    const TexelSamples& texels_;
    std::vector<uint32_t> texel_chart_;  // per covered texel: its chart (the guide's)
    std::vector<uint32_t> atlas_chart_;  // per atlas texel: its chart, kNoTexel where none
    ComputeProgram program_;
    GpuBuffer guide_;
};

}  // namespace lf
