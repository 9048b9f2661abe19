// The outputs a bake can produce, each one unit (DESIGN.md "Data flow"): its
// name, what it is computed on, whether it needs a light, how its progress
// is counted and stopped, and the files it writes. The settings catalog
// (bake_settings.h) holds each output's settings under its name; the job
// driver (gi/bake) holds a factory per name. Everything else — the spec's
// validation, the CLI's flags and progress bar, the server's ETA, the status
// page — loops over this registry and names no output.
//
// A new output is: its entry here, its settings in the catalog, and its
// method in gi/bake (docs/ARCHITECTURE.md, "A new output").
#pragma once

#include <string>
#include <vector>

namespace lf::protocol {

// What an output's values are attached to.
enum class OutputDomain {
    Texel,   // the lightmap atlas's texels (needs the atlas)
    Vertex,  // the scene's vertices
    Probe,   // points in space
};

// One file an output writes (its method's manifest section says what each
// holds). `name` may hold the snapshot pattern "pass-NNNN" (snapshot_file_name).
struct OutputFile {
    std::string name;
    std::string content_type;
};

struct OutputKind {
    std::string name;  // the spec's key under "outputs", the CLI's --NAME, the catalog's group
    std::string help;  // what --NAME asks for
    OutputDomain domain = OutputDomain::Texel;
    // Black without an emitter, a punctual light or a sky: refused at submit.
    bool needs_light = false;
    // A flag setting of this output that puts it on the atlas as well
    // (a per-vertex output also baked per texel); "" when none.
    std::string per_texel_setting;
    // Its stop settings are the catalog's PREFIX + "passes", "target_error", "time_limit".
    std::string stop_prefix;
    // What one of its passes is (progress bars and docs).
    std::string pass_unit;
    // Where its final image goes in scene.lit.glb: "lightmap" (the lit
    // material's light), "occlusion" (the material's occlusionTexture), or
    // "" (not in the lit scene).
    std::string lit_scene_slot;
    std::vector<OutputFile> files;
};

// Every output, in the order a job bakes them.
const std::vector<OutputKind>& output_registry();
// The output called `name`, or null.
const OutputKind* find_output(const std::string& name);
// The names of output_registry(), in order.
const std::vector<std::string>& output_names();

// The HTTP content type of a bake's file, from the registry's files (by
// name or snapshot pattern), else from its extension.
std::string content_type_of(const std::string& file);

}  // namespace lf::protocol
