// glTF files that carry SH transfer, and shading them for a person to look at.
//
// scene.sh.glb: the input scene with the transfer as vertex attributes
// _SH_TRANSFER_0 … _SH_TRANSFER_{K-1} (VEC4 float; attribute k holds
// coefficients 4k .. 4k+3; K = ceil(bands²/4), unused lanes zero) on every
// primitive, positions unchanged (seed §2.4: "SH coefficients of the geometry
// will be provided as vertex attributes (each attribute has 4 floating-point
// elements)").
#pragma once

#include "scene/scene.h"
#include "sh/environment.h"
#include "sh/sh_basis.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace lf {

int sh_attribute_count(int bands);  // (bands² + 3) / 4

// Writes `out_glb` from the file `scene` was loaded from; per_vertex is per
// Scene vertex, truncated to `bands`. Atomic; throws std::runtime_error.
void write_sh_glb(const std::filesystem::path& source_gltf, const Scene& scene,
                  const std::vector<ShCoefficients>& per_vertex, int bands, const std::filesystem::path& out_glb);

// The transfer stored in a scene.sh.glb, per vertex of `scene` (which must be
// lf::load_scene of that same file); bands from its attribute count.
std::vector<ShCoefficients> read_sh_glb_transfer(const std::filesystem::path& sh_glb, const Scene& scene,
                                                 int* bands = nullptr);

struct ShShadeOptions {
    // The scene a .bin transfer belongs to (the baked input, or its
    // scene.sh.glb); unused when the transfer is a .glb.
    std::filesystem::path scene;
    ShWindow window = ShWindow::None;  // applied when the environment is projected here
    int bands = 0;                     // 0: every band the transfer has
};

// `lightfarm sh-shade TRANSFER ENV --out shaded.glb`: TRANSFER is a
// scene.sh.glb or an sh_transfer.bin (then options.scene is needed), ENV an
// env_sh.json, an .exr/.hdr environment or "R,G,B". Writes the scene with
// COLOR_0 = E/pi per vertex (E = Σ T_i L_i, the radiance a white surface
// reflects) clamped to [0, 1] as glTF requires of a float colour, the values
// themselves in _E_OVER_PI (VEC3 float), and KHR_materials_unlit on its
// materials, so any glTF viewer shows base colour x COLOR_0 = albedo x E/pi.
// An existing COLOR_0 is replaced. Returns a summary: vertices, bands,
// min/max of E/pi, the counts of negative and of saturated (> 1) vertices.
nlohmann::json shade_sh_glb(const std::filesystem::path& transfer, const std::string& env,
                            const std::filesystem::path& out_glb, const ShShadeOptions& options = {});

}  // namespace lf
