// A whole bake, as `lightfarm bake` and the service's worker run it: load the
// scene, prepare the atlas and the tracer, run the method's progressive loop,
// write the files of DESIGN.md "Outputs" into one directory.
#pragma once

#include "bake/radiosity_map_baker.h"
#include "gpu/context.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <functional>
#include <string>

namespace lf {

struct BakeSettings {
    std::filesystem::path scene;
    std::filesystem::path out;
    int resolution = 0;          // atlas side in texels (0: from texel density, or 256)
    float texel_density = 0.0f;  // texels per metre (0: from resolution)
    StopRule stop;
    RadiosityMapSettings radiosity;
    DeviceChoice device = DeviceChoice::Auto;
    int subsamples_per_axis = 2;  // sample points per texel = this squared
    bool stitch_seams = true;
};

// Bake events, one JSON object each: {"event": "start" | "progress" |
// "snapshot" | "done", …}. This is the worker protocol the service reads
// (one object per line on stdout with `lightfarm bake --json`).
using BakeEventSink = std::function<void(const nlohmann::json&)>;

// Runs the bake and returns the "done" event. Throws on any failure; no file
// is ever left half-written under its final name.
nlohmann::json bake_lightmap(const BakeSettings& settings, const BakeEventSink& emit);

}  // namespace lf
