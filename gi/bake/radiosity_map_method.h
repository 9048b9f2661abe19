// The lightmap output of a bake job: RadiosityMapBaker's passes plus seam
// stitching and the EXR writer (DESIGN.md "Outputs": lightmap.exr and its
// snapshots lightmap.pass-NNNN.exr).
#pragma once

#include "atlas/seams.h"
#include "bake/lightmap_denoiser.h"
#include "bake/prepared_scene.h"
#include "bake/progressive.h"
#include "bake/radiosity_map_baker.h"
#include "bake_settings.h"

#include <optional>
#include <vector>

namespace lf {

class RadiosityMapMethod : public ProgressiveMethod {
public:
    // `prepared` must have an atlas; it outlives the method.
    RadiosityMapMethod(const PreparedScene& prepared, const protocol::BakeSettings& settings);

    std::string output() const override { return "lightmap"; }
    StopRule stop_rule() const override { return stop_; }
    nlohmann::json description() const override;
    uint64_t rays_per_pass() const override;
    PassStats step() override { return baker_.step(); }
    std::vector<PassStats> run_passes(int count) override { return baker_.run_passes(count); }
    int max_batch() const override { return baker_.max_batch(); }
    SnapshotWrite snapshot(const std::filesystem::path& dir, const PassStats& stats) override;
    MethodResult finish(const std::filesystem::path& dir, const PassStats& stats) override;
    MethodState state() const override { return baker_.state(); }
    void restore(const MethodState& state) override { baker_.restore(state); }

private:
    // The baker's image with the job's attributes, seams stitched (a
    // snapshot's `during_passes`); with `denoiser`, filtered before
    // stitching (the filter stops at chart borders).
    FloatImage stitched_image(const RadiosityMapBaker::Readback& readback, bool during_passes,
                              const LightmapDenoiser* denoiser = nullptr) const;

    const PreparedScene& prepared_;
    StopRule stop_;
    nlohmann::json settings_json_;
    RadiosityMapBaker baker_;
    std::vector<SeamEdge> seams_;               // smooth seams only (measured even when not stitched)
    std::optional<SeamStitcher> stitcher_;      // built once (none with --no-stitch): one system for every image
    std::optional<LightmapDenoiser> denoiser_;  // with --denoise
    // The last snapshot's image (set on the writer thread; finish() runs
    // after the writer drained): the final image when the bake stops on a
    // snapshot's pass.
    FloatImage last_snapshot_;
    int last_snapshot_pass_ = 0;
};

// The baker's settings for a job's lightmap settings and its environment
// (PreparedScene::environment; public for tests).
RadiosityMapSettings radiosity_settings(const protocol::BakeSettings& settings,
                                        const std::optional<Environment>& environment);

}  // namespace lf
