// `lightfarm compare`: the error of a baked output against a reference, as
// the JSON the command prints. Lightmaps (.exr) by lf::compare_to_reference,
// SH transfer files (.bin) by the relative RMSE of their coefficients. Here,
// not in the CLI, so that a test can call it and get the same numbers.
#pragma once

#include <nlohmann/json.hpp>

#include <optional>
#include <string>

namespace lf {

struct OutputComparisonOptions {
    // Texels whose mask's first channel is > 0.5 are compared (a .pfm, else
    // read as EXR). Without one, the bake's "covered" channel decides.
    std::optional<std::string> mask;
    // "direct", "indirect", "raw": that layer (its prefix.R/G/B channels) of
    // both lightmaps instead of their RGB.
    std::optional<std::string> layer;
    // Side of the squares of texels whose means are compared (1: texel by
    // texel); see compare_to_reference.
    int block = 1;
};

// Lightmaps: relative_rmse, rmse, bias, reference_mean, texels, block,
// worst_2_percent_share, twice_too_bright, half_too_dark, outlier_share
// (ReferenceError), and the bake's pass, rays, seconds, errorEstimate and denoiseSeconds where its
// header has them. Throws std::runtime_error naming the file and the
// channel when a --layer channel is missing.
nlohmann::json compare_lightmaps(const std::string& bake_path, const std::string& reference_path,
                                 const OutputComparisonOptions& options);

// Two SH transfer files of one scene: relative_rmse of the coefficients over
// the bands both hold, vertices, coefficients. Throws when their primitives
// or vertex counts differ.
nlohmann::json compare_sh_transfers(const std::string& bake_path, const std::string& reference_path);

// Two bake folders (each with lightmap.exr and scene.lightmapped.glb), at
// points of the scene's surfaces (compare_at_surface_points): bakes with
// different atlases. relative_rmse, rmse, bias, reference_mean, points,
// each one's covered texels (bake_texels, reference_texels), and the bake's
// header as compare_lightmaps's. `options.layer` applies; a mask or a block
// are texels of one atlas and are refused (std::invalid_argument).
nlohmann::json compare_bake_folders(const std::string& bake_folder, const std::string& reference_folder,
                                    const OutputComparisonOptions& options);

// By the bake's name: a folder is a bake folder (compare_bake_folders), a
// .bin an SH transfer file (the options do not apply to it and are
// ignored), anything else a lightmap.
nlohmann::json compare_outputs(const std::string& bake_path, const std::string& reference_path,
                               const OutputComparisonOptions& options);

}  // namespace lf
