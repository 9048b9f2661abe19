#include "io/reference_error.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace lf {

FloatImage downsample(const FloatImage& image, int factor, bool is_mask) {
    FloatImage out;
    out.width = image.width / factor;
    out.height = image.height / factor;
    for (const auto& [name, data] : image.channels) {
        std::vector<float>& d = out.channel(name);
        for (int y = 0; y < out.height; ++y)
            for (int x = 0; x < out.width; ++x) {
                double sum = 0.0;
                bool all = true;
                for (int j = 0; j < factor; ++j)
                    for (int i = 0; i < factor; ++i) {
                        const float v = data[size_t(y * factor + j) * size_t(image.width) + size_t(x * factor + i)];
                        sum += v;
                        all = all && v > 0.5f;
                    }
                d[size_t(y) * size_t(out.width) + size_t(x)] =
                    is_mask ? (all ? 1.0f : 0.0f) : float(sum / double(factor * factor));
            }
    }
    return out;
}

namespace {

// One compared texel: its squared error over the three channels, the two
// channel means, and the noise both files say they have there.
struct TexelError {
    double squared = 0.0, bake = 0.0, reference = 0.0, noise = 0.0;
};

TexelError texel_error(const FloatImage& bake, const FloatImage& reference, size_t i) {
    TexelError t;
    for (const char* c : {"R", "G", "B"}) {
        const double b = bake.at(c)[i], r = reference.at(c)[i];
        t.squared += (b - r) * (b - r);
        t.bake += b / 3.0;
        t.reference += r / 3.0;
    }
    for (const FloatImage* image : {&bake, &reference})
        if (image->channels.count("error")) t.noise += image->at("error")[i];
    return t;
}

// ReferenceError's worst_2_percent_share, twice_too_bright, half_too_dark
// and outlier_share.
void find_outliers(std::vector<TexelError>& texels, double reference_mean, ReferenceError& e) {
    double total = 0.0, outliers = 0.0;
    for (const TexelError& t : texels) {
        total += t.squared;
        const double margin = 3.0 * t.noise + 0.1 * reference_mean;
        const bool bright = t.bake > 2.0 * t.reference && t.bake - t.reference > margin;
        const bool dark = t.reference > 2.0 * t.bake && t.reference - t.bake > margin;
        e.twice_too_bright += bright;
        e.half_too_dark += dark;
        if (bright || dark) outliers += t.squared;
    }
    if (total <= 0.0) return;
    const size_t worst = std::max<size_t>(1, texels.size() / 50);
    std::nth_element(texels.begin(), texels.begin() + long(worst - 1), texels.end(),
                     [](const TexelError& a, const TexelError& b) { return a.squared > b.squared; });
    double worst_sum = 0.0;
    for (size_t k = 0; k < worst; ++k) worst_sum += texels[k].squared;
    e.worst_2_percent_share = worst_sum / total;
    e.outlier_share = outliers / total;
}

}  // namespace

ReferenceError compare_to_reference(const FloatImage& bake, const FloatImage& full_reference,
                                    const FloatImage* full_mask, int block) {
    const int factor = bake.width > 0 ? full_reference.width / bake.width : 0;
    FloatImage reduced_reference, reduced_mask;
    const FloatImage* reference_ptr = &full_reference;
    const FloatImage* mask = full_mask;
    if (factor > 1 && bake.width * factor == full_reference.width && bake.height * factor == full_reference.height) {
        reduced_reference = downsample(full_reference, factor, false);
        reference_ptr = &reduced_reference;
        if (full_mask) {
            reduced_mask = downsample(*full_mask, factor, true);
            mask = &reduced_mask;
        }
    }
    const FloatImage& reference = *reference_ptr;
    if (bake.width != reference.width || bake.height != reference.height)
        throw std::runtime_error("the bake is " + std::to_string(bake.width) + "x" + std::to_string(bake.height) +
                                 " but the reference is " + std::to_string(reference.width) + "x" +
                                 std::to_string(reference.height));
    if (mask && (mask->width != bake.width || mask->height != bake.height))
        throw std::runtime_error("the mask's size differs from the bake's");
    const char* names[3] = {"R", "G", "B"};
    const std::vector<float>* mask_channel = mask ? &mask->channels.begin()->second : nullptr;
    if (!mask_channel && bake.channels.count(kCoveredChannel)) mask_channel = &bake.channels.at(kCoveredChannel);
    if (block < 1) throw std::runtime_error("the block side must be at least 1 texel");
    // Per block: its compared texels' count and their sums in each channel.
    struct BlockSums {
        size_t texels = 0;
        double bake[3] = {0.0, 0.0, 0.0}, reference[3] = {0.0, 0.0, 0.0};
    };
    const int blocks_x = (bake.width + block - 1) / block, blocks_y = (bake.height + block - 1) / block;
    std::vector<TexelError> texel_errors;
    std::vector<BlockSums> blocks(size_t(blocks_x) * size_t(blocks_y));
    for (int y = 0; y < bake.height; ++y)
        for (int x = 0; x < bake.width; ++x) {
            const size_t i = size_t(y) * size_t(bake.width) + size_t(x);
            if (mask_channel) {
                if (!((*mask_channel)[i] > 0.5f)) continue;
            } else if (reference.at("R")[i] == 0.0f && reference.at("G")[i] == 0.0f && reference.at("B")[i] == 0.0f) {
                continue;
            }
            BlockSums& b = blocks[size_t(y / block) * size_t(blocks_x) + size_t(x / block)];
            ++b.texels;
            texel_errors.push_back(texel_error(bake, reference, i));
            for (int c = 0; c < 3; ++c) {
                b.bake[c] += bake.at(names[c])[i];
                b.reference[c] += reference.at(names[c])[i];
            }
        }
    // Each block's mean error counted once per texel it holds: with 1x1
    // blocks, the texels' RMSE; the bias is the same at every block size.
    double sum_sq = 0.0, sum_bake = 0.0, sum_ref = 0.0;
    size_t texels = 0;
    for (const BlockSums& b : blocks) {
        if (b.texels == 0) continue;
        texels += b.texels;
        for (int c = 0; c < 3; ++c) {
            const double difference = (b.bake[c] - b.reference[c]) / double(b.texels);
            sum_sq += double(b.texels) * difference * difference;
            sum_bake += b.bake[c];
            sum_ref += b.reference[c];
        }
    }
    ReferenceError e;
    e.texels = texels;
    if (texels == 0) return e;
    find_outliers(texel_errors, sum_ref / (3.0 * double(texels)), e);
    const double n = 3.0 * double(texels);
    e.rmse = std::sqrt(sum_sq / n);
    e.reference_mean = sum_ref / n;
    e.relative_rmse = e.reference_mean > 0.0 ? e.rmse / e.reference_mean : 0.0;
    e.bias = sum_ref > 0.0 ? sum_bake / sum_ref - 1.0 : 0.0;
    return e;
}

}  // namespace lf
