#include "io/output_comparison.h"

#include "io/image_files.h"
#include "io/reference_error.h"
#include "sh/transfer_file.h"

#include <algorithm>
#include <cmath>
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

}  // namespace

nlohmann::json compare_lightmaps(const std::string& bake_path, const std::string& reference_path,
                                 const OutputComparisonOptions& options) {
    FloatImage bake = read_exr(bake_path);
    FloatImage reference = read_exr(reference_path);
    if (options.layer) {
        const std::string prefix = *options.layer + ".";
        bake = layer_of(bake, prefix, bake_path);
        // A reference that was never filtered (Cycles', a bake without
        // --denoise) is its own raw layer: a denoised bake's raw layer is
        // measured against its RGB.
        if (!(prefix == "raw." && !reference.channels.count("raw.R")))
            reference = layer_of(reference, prefix, reference_path);
    }
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
    // The bake's own record of how it was made, under its name without "lightfarm.".
    for (const char* key : {"lightfarm.pass", "lightfarm.rays", "lightfarm.seconds", "lightfarm.errorEstimate",
                            "lightfarm.denoiseSeconds"}) {
        auto it = bake.number_attributes.find(key);
        if (it != bake.number_attributes.end()) out[std::string(key).substr(10)] = it->second;
    }
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
    if (ends_with(bake_path, ".bin")) return compare_sh_transfers(bake_path, reference_path);
    return compare_lightmaps(bake_path, reference_path, options);
}

}  // namespace lf
