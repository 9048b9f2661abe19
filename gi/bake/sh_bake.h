// A whole SH transfer bake, as `lightfarm bake --sh` and the service's worker
// run it: load the scene, build the tracer, run the transfer's progressive
// loop, choose the band count, write the files of DESIGN.md "Outputs".
// Same event protocol as bake_lightmap (gi/bake/bake.h).
#pragma once

#include "bake/bake.h"
#include "bake/sh_transfer_baker.h"
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
};

// Writes into settings.out:
//   scene.sh.glb                the input with _SH_TRANSFER_k attributes
//   sh_transfer.bin             float32 coefficients (format: gi/sh/transfer_file.h)
//   sh_transfer.half.bin        the same in float16 (size and error in the manifest)
//   sh_transfer.pass-NNNN.bin   snapshots on passes 1, 2, 4, 8 …
//   env_sh.json                 when an environment is given
//   manifest.json               its "sh" section (other sections of an existing manifest are kept)
// Events: start, progress, snapshot, done (as bake_lightmap). Returns "done".
nlohmann::json bake_sh(const ShBakeSettings& settings, const BakeEventSink& emit);

}  // namespace lf
