// The probes output of a bake job (Umenhoffer & Szirmay-Kalos, "Robust
// Diffuse Final Gathering on the GPU"): light probes for dynamic objects.
// Each probe is a cube map from its reference point of the radiance and the
// distance of the surfaces it sees (gi/shaders/probe_capture.comp, one ray
// and path per texel per pass through the job's one tracer), downsampled to
// M x M per face and written as probes.exr + probes.json (gi/probes/probe_set.h).
//
// Placement models no more than the scene needs: explicit points (the job's
// probe_positions, else the glTF nodes whose extras hold "lightfarm_probe":
// true), or a grid over the scene's bounds; a probe whose rays mostly meet the backs of
// one-sided surfaces is inside geometry and is dropped, and so is a grid
// probe far from every surface. probes.json says which were kept and why.
#pragma once

#include "bake/prepared_scene.h"
#include "bake/method_state.h"
#include "bake/progressive.h"
#include "bake/scene_shading.h"
#include "trace/surface_textures.h"
#include "bake_settings.h"
#include "job_spec.h"

#include <optional>
#include "gpu/shader.h"
#include "probes/probe_set.h"
#include "shaders/probes_params.glsl"

#include <vector>

namespace lf {

// The probes output's settings (the catalog's "probes" group) as the method runs them.
struct ProbesSettings {
    std::vector<glm::vec3> positions;  // explicit reference points; empty: a grid
    std::optional<double> spacing;     // grid spacing in metres; empty: auto (from the scene's extent)
    int res = 0;                       // R: capture texels per cube face side
    int m = 0;                         // M: texels per face side after downsampling (divides R)
    static ProbesSettings from(const protocol::OutputSettings& settings);
};

// A job's settings for probes at `points` only, captured at R = `r` and
// downsampled to `m`, the catalog's defaults for the rest (tests and benches).
protocol::BakeSettings probes_at(const std::vector<glm::vec3>& points, int r, int m, uint32_t seed = 1);

class ProbesMethod : public ProgressiveMethod {
public:
    // A probe is inside geometry when more of its rays than this meet backs.
    static constexpr float kInsideBackfaceFraction = 0.25f;
    // A grid probe is far from every surface when its nearest hit is farther
    // than this many grid spacings.
    static constexpr float kFarInSpacings = 1.5f;
    // A grid probe closer to a surface than this (metres, and at most a
    // quarter spacing) is moved away from it first (Probe::moved_from): from
    // 1 cm above a floor the floor fills half its view at grazing angles, and
    // its polygons carry nothing of what lies beyond the points it serves.
    static constexpr float kClearance = 0.1f;

    // Throws BakeInputError for a grid or capture too large.
    ProbesMethod(const PreparedScene& prepared, const protocol::BakeSettings& settings);

    std::string output() const override { return "probes"; }
    StopRule stop_rule() const override { return stop_; }
    nlohmann::json description() const override;
    uint64_t rays_per_pass() const override;
    PassStats step() override;
    SnapshotWrite snapshot(const std::filesystem::path& dir, const PassStats& stats) override;
    MethodResult finish(const std::filesystem::path& dir, const PassStats& stats) override;
    // The capture texels' running sums (the ray counter is 0 between passes).
    MethodState state() const override;
    void restore(const MethodState& state) override;

    // The reference points a job's settings place in a scene (explicit, or
    // the grid), before validity is known. Public for tests.
    static std::vector<glm::vec3> place(const Scene& scene, const ProbesSettings& settings, float* spacing);

    // The set as captured so far (reads the GPU's accumulators back).
    ProbeSet probe_set() const { return probe_set(texels_.read<glm::vec4>()); }

private:
    // The set from read-back accumulators (any thread: reads only what the
    // constructor set).
    ProbeSet probe_set(const std::vector<glm::vec4>& accumulators) const;
    ProbesParams params() const;
    // Every probe's corner distances (or with `centres`, its texels' centre
    // distances) by one ray each (probe_corners.comp).
    std::vector<float> trace_grid_distances(bool centres) const;
    // Grid probes within the clearance of a surface, moved away from it
    // (along the corner ray that met it nearest) until they are not, in at
    // most three steps; returns the placement's points of those moved.
    void move_away_from_surfaces();
    uint64_t state_layout() const { return hash_vector(positions_, uint64_t(settings_.res)); }
    const PreparedScene& prepared_;
    ProbesSettings settings_;
    StopRule stop_;
    uint32_t seed_;
    float spacing_ = 0.0f;  // 0 for explicit points
    std::vector<glm::vec3> positions_;
    std::vector<std::optional<glm::vec3>> moved_from_;  // per probe: its placement's point, if moved
    SceneShading shading_;
    SurfaceTextures surface_textures_;  // paths reflect the textures where they land
    ComputeProgram capture_;
    GpuBuffer positions_buffer_, texels_, rays_;
    std::vector<float> corner_distances_;  // per probe 6·(M+1)² (Probe::corner_distance)
    std::vector<float> centre_distances_;  // per probe 6·M² (Probe::centre_distance)
    PassStats stats_;
};

}  // namespace lf
