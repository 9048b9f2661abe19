// What the job driver prepares once per job and every method reads: the
// scene, the lightmap atlas and its texel samples (when a per-texel output is
// asked for), one GL context and one tracer.
#pragma once

#include "atlas/atlas.h"
#include "atlas/texel_samples.h"
#include "bake/double_sided.h"
#include "gpu/context.h"
#include "scene/scene.h"
#include "sh/environment.h"
#include "trace/tracer.h"
#include "util/stopwatch.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace lf {

struct PreparedScene {
    std::filesystem::path file;  // the glTF as given (writers copy it)
    Scene scene;                 // as loaded: per-vertex methods (SH) read its vertices
    // With the lightmap atlas as uv1 (vertices split on chart borders; the
    // triangles, their order and positions are the scene's): per-texel methods.
    std::optional<Scene> atlas_scene;
    AtlasReport atlas;
    TurnedCharts turned;              // double-sided charts baked for their back, which faces the scene
    size_t glass_charts = 0;          // packed at kUnlitChartScale, among AtlasReport::unlit_charts (find_glass_charts)
    uint64_t unlit_chart_rays = 0;    // traced to find the charts no light reaches (AtlasReport::unlit_charts)
    uint64_t light_density_rays = 0;  // traced for a first look at the light (atlas.light_density)
    TexelSamples texels;
    std::unique_ptr<GpuContext> gpu;
    // One BVH for every method: triangle t is the same triangle at the same
    // position in scene and atlas_scene, so it is built from the scene, and
    // takes atlas_scene's winding (Tracer::rewind) where double-sided charts
    // were turned.
    std::unique_ptr<Tracer> tracer;
    // The job's environment (--env), read once: a uniform sky, a map, or
    // none (escaping rays see black).
    std::optional<Environment> environment;
    double prepare_seconds = 0.0;
    // What preparation did otherwise than asked (the start event's and the
    // manifest's "warnings").
    std::vector<std::string> warnings;
    // Where preparation's time went, stage by stage (load, atlas,
    // texel_samples, gpu, bvh, methods): manifest.json's "prepared".
    std::vector<std::pair<std::string, double>> stage_seconds;
    // Told as each stage begins (not a stage that runs inside another, such
    // as the BVH an atlas stage asks for): the job's "prepare" events.
    std::function<void(const PreparedScene&, const std::string& stage)> on_stage;

    // Runs `stage` and records its time under `name`.
    template <class F>
    auto timed(const std::string& name, F&& stage) {
        if (on_stage && stage_depth_ == 0) on_stage(*this, name);
        struct Record {
            PreparedScene* p;
            const std::string& name;
            Stopwatch clock;
            ~Record() {
                --p->stage_depth_;
                p->stage_seconds.emplace_back(name, clock.seconds());
            }
        } record{this, name, {}};
        ++stage_depth_;
        return stage();
    }

private:
    int stage_depth_ = 0;
};

// The atlas as every per-texel method's manifest section describes it.
inline nlohmann::json atlas_json(const AtlasReport& atlas) {
    return {{"width", atlas.width},
            {"height", atlas.height},  // with pages: all of them stacked, page_gap rows apart
            {"pages", atlas.pages.count},
            {"page_height", atlas.pages.count > 1 ? atlas.pages.rows : atlas.height},
            {"page_gap", atlas.pages.gap},
            {"texel_density", atlas.texel_density},
            {"density_from_scene", atlas.density_from_scene},
            {"border_fraction", atlas.border_fraction},
            {"generated", atlas.generated},
            {"charts", atlas.charts},
            {"unlit_charts", atlas.unlit_charts},
            {"mesh_scaled_charts", atlas.mesh_scaled_charts},
            {"unmapped_charts", atlas.unmapped_charts},
            {"unlit_area_fraction", atlas.unlit_area_fraction},
            {"light_scaled_charts", atlas.light_scaled_charts},
            {"utilisation", atlas.utilisation}};
}

}  // namespace lf
