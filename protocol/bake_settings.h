// The one settings type of a bake: every setting's name, flag, type, range,
// default and help live once, in setting_catalog(), and one function
// (parse_bake_settings) decides what is valid. The CLI's `bake` flags, the
// server's job validation, the OpenAPI document, the README's option table and
// the worker (`lightfarm bake --spec SPEC.json`) all go through it, so a value
// is valid in one place exactly when it is valid in all.
//
// JSON shape (the "bake" part of a job spec; every key optional but outputs):
//   {"outputs": {"lightmap": {"passes": 256, …}, "sh": {"sh_bands": "auto", …}},
//    "atlas":   {"res": 512},          // shared by every per-texel output
//    "seed": 1,
//    "env":     [0.5, 0.6, 0.8]}       // uniform sky radiance, or (CLI only) a map file
// On the command line each setting is `--name-with-dashes VALUE`; a flag
// setting is `--name` (or `--no-name` when it defaults to true); outputs are
// chosen by `--lightmap`, `--sh`, or by giving any of their own settings.
#pragma once

#include "outputs.h"

#include <nlohmann/json.hpp>

#include <array>
#include <cstdint>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace lf::protocol {

// A setting that does not validate. what() is "field: reason", e.g.
// "lightmap.passes: 0 is below the minimum 1"; field() is "lightmap.passes"
// (or the CLI flag, "--passes", when the value came from the command line).
class SpecError : public std::runtime_error {
public:
    SpecError(const std::string& field, const std::string& reason)
        : std::runtime_error(field.empty() ? reason : field + ": " + reason), field_(field) {}
    const std::string& field() const { return field_; }

private:
    std::string field_;
};

// Caps that a server puts on what a job may ask for, by limit key. The keys
// are the catalog's Setting::limit ("res", "pages", "passes", "time_limit") plus the
// job's own "max_seconds" and "max_attempts".
struct SpecLimits {
    std::map<std::string, double> caps = {
        {"res", 8192},        {"pages", 16}, {"passes", 100000}, {"time_limit", 4 * 3600}, {"max_seconds", 4 * 3600},
        {"max_attempts", 10},
    };
    // An environment map is a file on the machine that runs the bake: the
    // CLI may read one, a server must not be told to read its own files.
    bool allow_local_files = true;
    double cap(const std::string& key) const;  // +infinity when absent
};

// The most entries a list of glTF meshes may hold (a spec is small: a list
// is bounded like every other value).
inline constexpr size_t kMaxMeshList = 65536;
// A mesh's lightmap scale (its charts' texel density over the atlas's): a
// glTF extras lightfarm_lightmap_scale or the spec's atlas.mesh_scale, in
// [0, kMaxLightmapScale]; 0: no lightmap (it still casts and bounces light).
inline constexpr double kMaxLightmapScale = 64.0;

enum class SettingType {
    Integer,      // JSON integer; CLI "12"
    Number,       // JSON number; CLI "0.5"
    Choice,       // one of `choices`; CLI the word
    Flag,         // JSON bool; CLI --name (true) or --no-name (false) per its default
    MeshList,     // glTF mesh indices: JSON [0, 3]; CLI "0,3"
    MeshScales,   // glTF mesh index -> scale: JSON {"3": 2, "5": 0.25}; CLI "3=2,5=0.25"
    Environment,  // JSON [r, g, b] or a file name; CLI "R,G,B" or FILE
    Positions,    // points: JSON [{"position": [x, y, z]}, …]; CLI a JSON file of that (or the JSON itself)
};

struct Setting {
    std::string group;  // an output's name (outputs.h), "atlas", or "" (the job's own: seed, env)
    std::string name;   // JSON key, e.g. "texel_density"
    SettingType type = SettingType::Number;
    nlohmann::json default_value;  // "auto" where the engine chooses; null: none
    double min = 0, max = 0;       // Integer / Number: the range (min exclusive if min_exclusive)
    bool min_exclusive = false;
    bool accepts_auto = false;  // the string "auto" is a value of its own
    std::vector<std::string> choices;
    std::string limit;  // SpecLimits key that caps it, or ""
    std::string help;

    std::string flag() const;          // "--texel-density"; a flag defaulting to true: "--no-stitch"
    std::string field() const;         // "lightmap.passes", "atlas.res", "seed"
    std::string value_syntax() const;  // "N", "1..4|auto", "epochs|thesis|pathtrace", … (for usage text)
};

// Every setting, outputs first (in output order), then the atlas, then the job's.
const std::vector<Setting>& setting_catalog();
const Setting* find_setting(const std::string& group, const std::string& name);
const Setting* find_setting_by_flag(const std::string& flag);

// The typed settings, filled from validated JSON with the catalog's
// defaults (the catalog is where every default lives: nothing here repeats one).
struct StopSettings {
    int passes = 0;
    double target_error = 0.0;  // 0: no target
    double time_limit = 0.0;    // seconds, 0: none
};

// The largest atlas side the engine chooses by itself (atlas.max_res auto).
inline constexpr int kAutoMaxAtlasRes = 4096;

struct AtlasSettings {
    std::optional<int> res;               // empty: auto (the file's TEXCOORD_1 size, or the engine's default)
    std::optional<double> texel_density;  // texels per metre; empty: from res
    int subsamples = 0;                   // sample points per texel = this squared
    // The largest side of an atlas the engine sizes (res auto, or from
    // texel_density); empty: auto, kAutoMaxAtlasRes. A server's res limit
    // below that is written in here when the spec is parsed, so that the
    // worker keeps to the limit of the server that took the job.
    std::optional<int> max_res;
    // Where the charts at an asked texel_density do not fit one max_res
    // atlas, they go on up to this many pages of max_res² (README, "Atlas
    // pages"); 0 until parsed.
    int max_pages = 0;
    bool glass_texels = false;   // glass charts at the scene's density, not kUnlitChartScale's
    bool light_density = false;  // charts' density from a first look at their light (gi/bake/light_density.h)
    // Per glTF mesh, its charts' texel density over the atlas's (0: no
    // lightmap), over the file's own extras (lightfarm_lightmap_scale).
    std::map<int, double> mesh_scale;
};

// One requested output's settings: every setting of its catalog group,
// validated, in canonical JSON ("auto" where auto). Each method reads these
// into its own engine struct (gi/bake/*_method.h), as pbrt's
// Create(parameters) does; the rest of lightfarm reads only the stop rule.
struct OutputSettings {
    std::string output;  // its name (outputs.h)
    nlohmann::json values = nlohmann::json::object();

    // Its stop rule: the settings the registry names (OutputKind::stop_prefix).
    StopSettings stop() const;

    int integer(const std::string& name) const { return values.at(name).get<int>(); }
    double number(const std::string& name) const { return values.at(name).get<double>(); }
    bool flag(const std::string& name) const { return values.at(name).get<bool>(); }
    std::string choice(const std::string& name) const { return values.at(name).get<std::string>(); }
    std::optional<int> integer_or_auto(const std::string& name) const;
    std::optional<double> number_or_auto(const std::string& name) const;
};

// A uniform sky radiance or an environment map file (or nothing).
struct EnvironmentSetting {
    std::optional<std::array<float, 3>> sky;
    std::string map_file;
    bool given() const { return sky.has_value() || !map_file.empty(); }
};

struct BakeSettings {
    // The requested outputs by name (outputs.h), each with its settings.
    std::map<std::string, OutputSettings> outputs;
    AtlasSettings atlas;
    uint32_t seed = 1;
    // Each output's snapshots of its newest N passes are kept, older ones
    // removed as newer ones are written; 0 keeps all.
    int keep_snapshots = 0;
    EnvironmentSetting env;

    // The output `name`'s settings, or null when it was not asked for.
    const OutputSettings* output(const std::string& name) const;
    OutputSettings* output(const std::string& name);
    // Whether any requested output is baked on the lightmap atlas (a per-texel
    // output, or one whose per-texel setting is on).
    bool uses_atlas() const;
    // Whether any requested atlas output needs a light (only then may the
    // atlas shrink the charts no light reaches).
    bool atlas_needs_light() const;
    // Whether any requested output needs a light (outputs.h).
    bool needs_light() const;
};

// Validates the bake part of a spec ({"outputs", "atlas", "seed", "env"}; other
// keys are the caller's business and ignored) and fills the defaults. Throws
// SpecError naming the first bad field. This is THE validity rule.
BakeSettings parse_bake_settings(const nlohmann::json& j, const SpecLimits& limits = {});
// The canonical JSON of validated settings: every setting of every chosen
// output with its value ("auto" where auto), so equal JSON = equal bake.
nlohmann::json to_json(const BakeSettings& settings);

// The command line: flag -> text as typed (a Flag setting or an output flag
// maps to ""), applied over `base` (a spec's bake JSON, or {}). Flags win over
// the base; outputs named by flag (or by giving one of their settings) are
// added to those of the base; with none at all, the lightmap. Throws SpecError
// naming the flag.
nlohmann::json bake_json_from_flags(const std::map<std::string, std::string>& flags,
                                    const nlohmann::json& base = nlohmann::json::object());
// Every flag bake_json_from_flags knows: {flag, takes a value}.
std::vector<std::pair<std::string, bool>> bake_flags();

// Host memory a bake of an atlas of `atlas_texels` texels with `subsamples`²
// sample points per texel needs at its peak (texel samples, GPU buffers —
// host memory on llvmpipe — and the snapshot images). Measured (llvmpipe,
// the Cornell box, one pass, peak RSS): at 2 subsamples on 2026-11-23 at
// 512², 1024², 2048²: 0.22, 0.62, 2.21 GB; at 1024² on 2026-11-27 with 1, 2,
// 4 subsamples: 0.46, 0.63, 1.46 GB, about 70 bytes per sample point and
// atlas texel. The estimate, 130 MB + (260 + 72 s²) bytes per texel, is at or
// above every one of those. The engine refuses a bake whose estimate exceeds
// the memory available, with this figure in the message.
uint64_t estimated_bake_bytes(uint64_t atlas_texels, int subsamples);

}  // namespace lf::protocol
