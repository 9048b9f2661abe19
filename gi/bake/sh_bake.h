// A whole SH transfer bake, as `lightfarm bake --sh` and the service's worker
// run it: load the scene, build the tracer, run the transfer's progressive
// loop, choose the band count, write the files of DESIGN.md "Outputs".
// Same event protocol as bake_lightmap (gi/bake/bake.h).
#pragma once

#include "atlas/texel_samples.h"
#include "bake/bake.h"
#include "bake/sh_transfer_baker.h"
#include "io/image_files.h"
#include "sh/sh_basis.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>

namespace lf {

struct ShBakeSettings {
    std::filesystem::path scene;
    std::filesystem::path out;
    // --env: "" (none), an .exr/.hdr equirectangular map, or "R,G,B".
    std::string environment;
    ShWindow window = ShWindow::None;  // --sh-window none|hanning|lanczos, applied to env_sh.json
    int bands = kShMaxBands;           // --sh-bands 1..4, or 0 = auto
    // auto: the smallest band count whose shading error against 4 bands
    // (relative RMS over vertices, under the environment, or a uniform sky
    // without one) is at most this.
    double auto_bands_error = 0.02;
    ShTransferSettings transfer;        // --sh-bounces → transfer.bounces, --seed → transfer.seed
    StopRule stop;                      // --passes, --target-error, --time-limit
    DeviceChoice device = DeviceChoice::Auto;
    // --sh-per-texel (as the D3DX PRT engine offered): the transfer also at
    // the lightmap atlas's texel sample points, written to sh_transfer.exr.
    // The atlas is the lightmap's (prepare_lightmap_atlas): the scene's
    // TEXCOORD_1, or generated at this resolution / texel density (the bake's
    // --res / --texel-density; both 0: 256, as the lightmap).
    bool per_texel = false;
    int per_texel_resolution = 0;
    float per_texel_density = 0.0f;
    // Sample points per texel = this squared (rasterize_texel_samples; each
    // traces samples_per_pass rays a pass, the texel is their mean).
    int per_texel_subsamples = 1;
};

// Per-texel transfer (--sh-per-texel), the pieces bake_sh uses, public for tests.
// The receiver points of a lightmap atlas's texel samples: one per sample on
// a triangle of a receiver mesh (ShTransferSettings::receiver_meshes, empty =
// all); a sample elsewhere is not traced and gets the unoccluded transfer of
// its normal, as a non-receiver vertex does. `atlas_scene` is the scene the
// samples were rasterized from (its instances say which mesh a triangle is of).
struct ShTexelReceivers {
    std::vector<ShReceiverPoint> points;
    std::vector<int64_t> point_of_sample;  // per TexelSamples::samples entry: index into points, or -1
};
ShTexelReceivers sh_texel_receivers(const Scene& atlas_scene, const TexelSamples& texels,
                                    const std::vector<int>& receiver_meshes);

// sh_transfer.exr's image: width x height of the atlas, rows from the top
// (DESIGN.md image space), channels
//   "sh.0" … "sh.{bands²-1}"  transfer coefficient i (index l(l+1)+m, the real
//                            orthonormal basis of gi/sh/sh_basis.h): the mean
//                            over the texel's sample points;
//   "coverage"               1 on covered texels, 0 elsewhere (dilated ones too).
// Covered texels are dilated past chart borders (TexelSamples::dilation); the
// rest are 0. Attributes: lightfarm.bands, lightfarm.sh_ordering.
// `point_transfer` is ShVertexTransfer::point_coefficients for `receivers`.
FloatImage sh_texel_image(const TexelSamples& texels, const ShTexelReceivers& receivers,
                          const std::vector<ShCoefficients>& point_transfer, int bands);

// Writes into settings.out:
//   scene.sh.glb                the input with _SH_TRANSFER_k attributes
//   sh_transfer.bin             float32 coefficients (format: gi/sh/transfer_file.h)
//   sh_transfer.half.bin        the same in float16 (size and error in the manifest)
//   sh_transfer.pass-NNNN.bin   snapshots on passes 1, 2, 4, 8 …
//   env_sh.json                 when an environment is given
//   sh_transfer.exr             per_texel: per-texel transfer (layout: sh_texel_image)
//   sh_transfer.pass-NNNN.exr   per_texel: its snapshots on passes 1, 2, 4, 8 …
//   scene.lightmapped.glb       per_texel with a generated atlas: the input with TEXCOORD_1
//   manifest.json               its "sh" section (other sections of an existing manifest are kept)
// Events: start, progress, snapshot, done (as bake_lightmap). Returns "done".
nlohmann::json bake_sh(const ShBakeSettings& settings, const BakeEventSink& emit);

}  // namespace lf
