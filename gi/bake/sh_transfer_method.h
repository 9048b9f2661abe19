// The SH transfer output of a bake job (Staniszewski 2005): ShTransferBaker's
// passes, the band choice, and the writers of DESIGN.md "Outputs".
#pragma once

#include "atlas/texel_samples.h"
#include "bake/prepared_scene.h"
#include "bake/progressive.h"
#include "bake/radiosity_map_method.h"
#include "bake/sh_transfer_baker.h"
#include "bake_settings.h"
#include "sh/environment.h"
#include "io/image_files.h"
#include "sh/sh_basis.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>

namespace lf {

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

// The SH output's settings (the catalog's "sh" group) as the method runs them.
struct ShSettings {
    std::optional<int> bands;  // empty: auto
    int bounces = 0;
    std::string window;
    std::vector<int> occluders, receivers;  // glTF mesh indices, empty = all
    bool per_texel = false;
    static ShSettings from(const protocol::OutputSettings& settings);
};

// The SH output of a bake job. Writes:
//   scene.sh.glb                the input with _SH_TRANSFER_k attributes
//   sh_transfer.bin             float32 coefficients (format: gi/sh/transfer_file.h)
//   sh_transfer.half.bin        the same in float16 (size and error in the manifest)
//   sh_transfer.pass-NNNN.bin   snapshots on passes 1, 2, 4, 8 …
//   env_sh.json                 when an environment is given
//   sh_transfer.exr             per_texel: per-texel transfer in the job's atlas (layout: sh_texel_image)
//   sh_transfer.pass-NNNN.exr   per_texel: its snapshots
class ShTransferMethod : public ProgressiveMethod {
public:
    // auto bands: the fewest whose shading error against 4 bands (relative
    // RMS over vertices, under the environment, or a uniform sky without one)
    // is at most this.
    static constexpr double kAutoBandsError = 0.02;

    // `prepared` outlives the method; with sh.per_texel it must have an atlas.
    // Throws BakeInputError for occluder/receiver meshes the scene does not draw.
    ShTransferMethod(const PreparedScene& prepared, const protocol::BakeSettings& settings);
    ~ShTransferMethod() override;

    std::string output() const override { return "sh"; }
    StopRule stop_rule() const override { return stop_; }
    nlohmann::json description() const override;
    uint64_t rays_per_pass() const override;
    PassStats step() override;
    SnapshotWrite snapshot(const std::filesystem::path& dir, const PassStats& stats) override;
    MethodResult finish(const std::filesystem::path& dir, const PassStats& stats) override;
    MethodState state() const override { return baker_->state(); }
    void restore(const MethodState& state) override { baker_->restore(state); }

private:
    FloatImage texel_image(const ShVertexTransfer& t, int bands, const PassStats& s) const;
    std::string bands_why(int bands) const;

    const PreparedScene& prepared_;
    ShSettings settings_;
    ShTransferSettings transfer_;
    StopRule stop_;
    const std::optional<Environment>& environment_;  // the prepared scene's
    ShWindow window_;
    int subsamples_;
    bool uniform_light_;  // a uniform sky (--env R,G,B): the same radiance from every direction
    ShTexelReceivers texel_receivers_;
    std::unique_ptr<ShTransferBaker> baker_;
    nlohmann::json settings_json_;
};

}  // namespace lf
