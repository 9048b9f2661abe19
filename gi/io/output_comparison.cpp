#include "io/output_comparison.h"

#include "io/image_files.h"
#include "io/reference_error.h"
#include "io/surface_comparison.h"
#include "scene/gltf_loader.h"
#include "sh/transfer_file.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <stdexcept>

namespace lf {

namespace {

bool ends_with(const std::string& s, const std::string& suffix) {
    return s.size() > suffix.size() && s.substr(s.size() - suffix.size()) == suffix;
}

// The layer `prefix` ("direct.", "indirect.", "raw.") of `image` as its R, G, B.
FloatImage layer_of(const FloatImage& image, const std::string& prefix, const std::string& file) {
    FloatImage layer = image;
    for (const char* c : {"R", "G", "B"}) {
        const auto it = image.channels.find(prefix + c);
        if (it == image.channels.end()) throw std::runtime_error(file + ": no channel " + prefix + c);
        layer.channels[c] = it->second;
    }
    return layer;
}

// A lightmap as compared: the image, or its --layer as its R, G, B.
FloatImage read_lightmap(const std::string& path, const std::optional<std::string>& layer, bool is_reference) {
    FloatImage image = read_exr(path);
    if (!layer) return image;
    const std::string prefix = *layer + ".";
    // A reference that was never filtered (Cycles', a bake without
    // --denoise) is its own raw layer: a denoised bake's raw layer is
    // measured against its RGB.
    if (is_reference && prefix == "raw." && !image.channels.count("raw.R")) return image;
    return layer_of(image, prefix, path);
}

// The bake's own record of how it was made, under its name without "lightfarm.".
void add_bake_header(nlohmann::json& out, const FloatImage& bake) {
    for (const char* key : {"lightfarm.pass", "lightfarm.rays", "lightfarm.seconds", "lightfarm.errorEstimate",
                            "lightfarm.denoiseSeconds"}) {
        auto it = bake.number_attributes.find(key);
        if (it != bake.number_attributes.end()) out[std::string(key).substr(10)] = it->second;
    }
}

size_t covered_texels(const FloatImage& image) {
    const auto it = image.channels.find(kCoveredChannel);
    if (it == image.channels.end()) return 0;
    return size_t(std::count_if(it->second.begin(), it->second.end(), [](float c) { return c > 0.5f; }));
}

}  // namespace

nlohmann::json compare_bake_folders(const std::string& bake_folder, const std::string& reference_folder,
                                    const OutputComparisonOptions& options) {
    if (options.mask || options.block != 1)
        throw std::invalid_argument(
            "--mask and --block compare the texels of one atlas; two bake folders are "
            "compared at points of the surface");
    const std::filesystem::path bake_dir(bake_folder), reference_dir(reference_folder);
    const FloatImage bake = read_lightmap((bake_dir / "lightmap.exr").string(), options.layer, false);
    const FloatImage reference = read_lightmap((reference_dir / "lightmap.exr").string(), options.layer, true);
    const Scene bake_scene = load_scene(bake_dir / "scene.lightmapped.glb");
    const Scene reference_scene = load_scene(reference_dir / "scene.lightmapped.glb");
    const SurfaceComparison e = compare_at_surface_points(bake_scene, bake, reference_scene, reference);
    nlohmann::json out = {{"relative_rmse", e.relative_rmse},
                          {"rmse", e.rmse},
                          {"bias", e.bias},
                          {"reference_mean", e.reference_mean},
                          {"points", e.points},
                          {"bake_texels", covered_texels(bake)},
                          {"reference_texels", covered_texels(reference)}};
    add_bake_header(out, bake);
    return out;
}

nlohmann::json compare_lightmaps(const std::string& bake_path, const std::string& reference_path,
                                 const OutputComparisonOptions& options) {
    const FloatImage bake = read_lightmap(bake_path, options.layer, false);
    const FloatImage reference = read_lightmap(reference_path, options.layer, true);
    FloatImage mask;
    if (options.mask) mask = ends_with(*options.mask, ".pfm") ? read_pfm(*options.mask) : read_exr(*options.mask);
    const ReferenceError e = compare_to_reference(bake, reference, options.mask ? &mask : nullptr, options.block);
    nlohmann::json out = {{"relative_rmse", e.relative_rmse},
                          {"rmse", e.rmse},
                          {"bias", e.bias},
                          {"reference_mean", e.reference_mean},
                          {"texels", e.texels},
                          {"block", options.block},
                          {"worst_2_percent_share", e.worst_2_percent_share},
                          {"twice_too_bright", e.twice_too_bright},
                          {"half_too_dark", e.half_too_dark},
                          {"outlier_share", e.outlier_share}};
    add_bake_header(out, bake);
    return out;
}

nlohmann::json compare_sh_transfers(const std::string& bake_path, const std::string& reference_path) {
    const ShTransferFile bake = read_sh_transfer(bake_path);
    const ShTransferFile reference = read_sh_transfer(reference_path);
    if (bake.primitives.size() != reference.primitives.size())
        throw std::runtime_error(bake_path + " and " + reference_path + " hold different primitives");
    const int coefficients = std::min(bake.bands, reference.bands) * std::min(bake.bands, reference.bands);
    double sum_sq = 0.0, sum_ref_sq = 0.0;
    size_t vertices = 0;
    for (size_t p = 0; p < bake.primitives.size(); ++p) {
        const auto &a = bake.primitives[p].vertices, &b = reference.primitives[p].vertices;
        if (a.size() != b.size()) throw std::runtime_error("primitive " + std::to_string(p) + ": vertex counts differ");
        for (size_t v = 0; v < a.size(); ++v)
            for (int i = 0; i < coefficients; ++i) {
                sum_sq += double(a[v][i] - b[v][i]) * double(a[v][i] - b[v][i]);
                sum_ref_sq += double(b[v][i]) * double(b[v][i]);
            }
        vertices += a.size();
    }
    // Relative to the reference's RMS coefficient.
    return nlohmann::json{{"relative_rmse", sum_ref_sq > 0.0 ? std::sqrt(sum_sq / sum_ref_sq) : 0.0},
                          {"vertices", vertices},
                          {"coefficients", coefficients}};
}

nlohmann::json compare_outputs(const std::string& bake_path, const std::string& reference_path,
                               const OutputComparisonOptions& options) {
    if (std::filesystem::is_directory(bake_path)) return compare_bake_folders(bake_path, reference_path, options);
    if (ends_with(bake_path, ".bin")) return compare_sh_transfers(bake_path, reference_path);
    return compare_lightmaps(bake_path, reference_path, options);
}

}  // namespace lf
