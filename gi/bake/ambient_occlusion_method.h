// The ao output of a bake job: an ambient-occlusion map of the lightmap
// atlas (DESIGN.md "Conventions": the cosine-weighted fraction of the
// hemisphere with no surface within the AO distance; 1 in the open, 0
// enclosed), the convention glTF's occlusionTexture and engines read.
// Needs no light. Writes:
//   ao.exr             R = G = B = ambient occlusion; layers samples, error, covered
//   ao.pass-NNNN.exr   snapshots on passes 1, 2, 4, 8 …
// and goes into scene.lit.glb as each material's occlusionTexture on TEXCOORD_1.
#pragma once

#include "bake/method_state.h"
#include "bake/prepared_scene.h"
#include "bake/progressive.h"
#include "bake_settings.h"
#include "gpu/shader.h"
#include "io/image_files.h"

#include <cstdint>
#include <filesystem>
#include <vector>

namespace lf {

// The ao output's settings (the catalog's "ao" group) as the method runs them.
struct AmbientOcclusionSettings {
    float distance = 0.0f;  // metres; a surface further than this does not occlude
    uint32_t seed = 0;
    // auto distance: this fraction of the scene's largest extent.
    static constexpr float kAutoDistanceOfExtent = 0.1f;
    static AmbientOcclusionSettings from(const protocol::OutputSettings& ao, uint32_t seed, const Scene& scene);
};

class AmbientOcclusionMethod : public ProgressiveMethod {
public:
    // `prepared` must have an atlas; it outlives the method.
    AmbientOcclusionMethod(const PreparedScene& prepared, const protocol::BakeSettings& settings);

    std::string output() const override { return "ao"; }
    StopRule stop_rule() const override { return stop_; }
    nlohmann::json description() const override;
    uint64_t rays_per_pass() const override;
    PassStats step() override { return run_passes(1).back(); }
    std::vector<PassStats> run_passes(int count) override;
    int max_batch() const override { return 64; }
    SnapshotWrite snapshot(const std::filesystem::path& dir, const PassStats& stats) override;
    MethodResult finish(const std::filesystem::path& dir, const PassStats& stats) override;
    MethodState state() const override;
    void restore(const MethodState& state) override;

private:
    // The map from the points' counts after `passes` passes (any thread).
    FloatImage image(const std::vector<float>& unoccluded, int passes) const;
    // The relative standard error of the mean occlusion (the stop rule's error).
    double error_estimate(const std::vector<float>& unoccluded, int passes) const;
    // Which atlas texel and sample point each count is (MethodState::layout).
    uint64_t layout() const;

    const PreparedScene& prepared_;
    AmbientOcclusionSettings settings_;
    StopRule stop_;
    nlohmann::json settings_json_;
    uint32_t point_count_ = 0;
    ComputeProgram program_;
    GpuBuffer points_, unoccluded_;
    PassStats stats_;
};

}  // namespace lf
