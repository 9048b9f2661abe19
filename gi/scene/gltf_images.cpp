#include "scene/gltf_images.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>

// stb_image from Debian's libstb-dev, compiled here as a private (static)
// copy: neither libtinygltf.so nor this library's link line exports
// stbi_info_from_memory, and a private copy lets us switch off every decoder
// glTF does not need (less code facing hostile bytes).
#define STB_IMAGE_STATIC
#define STB_IMAGE_IMPLEMENTATION
#define STBI_ONLY_PNG
#define STBI_ONLY_JPEG
#define STBI_NO_STDIO
#define STBI_NO_LINEAR
#define STBI_NO_HDR
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wimplicit-fallthrough"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#include <stb/stb_image.h>
#pragma GCC diagnostic pop

namespace lf::gltf {

namespace {

// Width and height from a PNG's IHDR chunk (signature, length, "IHDR", then
// both as big-endian 32-bit numbers); false if the bytes are not a PNG.
bool png_header_size(const unsigned char* bytes, size_t size, uint32_t* width, uint32_t* height) {
    static const unsigned char kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    if (size < 24 || std::memcmp(bytes, kSignature, 8) != 0 || std::memcmp(bytes + 12, "IHDR", 4) != 0) return false;
    auto be32 = [&](size_t at) {
        return uint32_t(bytes[at]) << 24 | uint32_t(bytes[at + 1]) << 16 | uint32_t(bytes[at + 2]) << 8 | bytes[at + 3];
    };
    *width = be32(16);
    *height = be32(20);
    return true;
}

}  // namespace

ImageDecoder::ImageDecoder(const Errors& errors, const LoadLimits& limits, std::vector<bool> used)
    : errors_(errors), limits_(limits), used_(std::move(used)), texels_left_(limits.max_total_texels) {}

bool ImageDecoder::callback(tinygltf::Image* image, const int image_index, std::string* err, std::string*, int, int,
                            const unsigned char* bytes, int size, void* self_ptr) {
    ImageDecoder& self = *static_cast<ImageDecoder*>(self_ptr);
    // Unused images are skipped, and bufferView images wait until the view is
    // validated: tinygltf computed `bytes` from an unchecked offset.
    if (!self.is_used(image_index) || image->bufferView >= 0) return true;
    try {
        self.decode(image, image_index, bytes, size_t(std::max(size, 0)));
        return true;
    } catch (const SceneError& e) {
        self.deferred_error_ = e.what();
        if (err) *err += self.deferred_error_ + "\n";
        return false;
    }
}

void ImageDecoder::check_dimensions(const std::string& label, uint32_t width, uint32_t height) const {
    const uint32_t limit = uint32_t(std::max(limits_.max_texture_dim, 0));
    if (width > limit || height > limit) {
        errors_.fail(label + ": dimensions " + std::to_string(width) + "x" + std::to_string(height) +
                     " exceed the limit of " + std::to_string(limit) + " texels per side");
    }
}

void ImageDecoder::decode(tinygltf::Image* image, int index, const unsigned char* bytes, size_t size) {
    const std::string label = Errors::label("image", index, image->name);
    if (size == 0 || bytes == nullptr) errors_.fail(label + ": no image data");
    if (size > size_t(std::numeric_limits<int>::max())) errors_.fail(label + ": encoded image over 2 GiB");

    // stb refuses a PNG over 1 GiB decoded without saying how large it
    // claims to be; the IHDR chunk says it, so a refusal can name the size.
    uint32_t claimed_width = 0, claimed_height = 0;
    if (png_header_size(bytes, size, &claimed_width, &claimed_height))
        check_dimensions(label, claimed_width, claimed_height);

    int width = 0, height = 0, channels = 0;
    if (!stbi_info_from_memory(bytes, int(size), &width, &height, &channels))
        errors_.fail(label + ": not a decodable PNG or JPEG image (" + stbi_failure_reason() + ")");
    if (width <= 0 || height <= 0) errors_.fail(label + ": image has no pixels");
    check_dimensions(label, uint32_t(width), uint32_t(height));
    const uint64_t texels = uint64_t(width) * uint64_t(height);
    if (texels > texels_left_) {
        errors_.fail(label + ": " + std::to_string(width) + "x" + std::to_string(height) +
                     " texels exceed what is left of the scene's texture budget (" +
                     std::to_string(limits_.max_total_texels) + " texels in all)");
    }

    // RGBA8 of the header's size: the pixels decoded, or none (header only).
    auto describe_rgba8 = [&] {
        image->width = width;
        image->height = height;
        image->component = 4;
        image->bits = 8;
        image->pixel_type = TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE;
        texels_left_ -= texels;
    };
    if (!limits_.decode_images) {  // header only: sizes known, no pixels
        image->image.clear();
        describe_rgba8();
        return;
    }
    int decoded_width = 0, decoded_height = 0, decoded_channels = 0;
    stbi_uc* pixels = stbi_load_from_memory(bytes, int(size), &decoded_width, &decoded_height, &decoded_channels, 4);
    if (pixels == nullptr) errors_.fail(label + ": image cannot be decoded (" + stbi_failure_reason() + ")");
    // The header was read twice; a decoder disagreeing with itself is not worth trusting.
    if (decoded_width != width || decoded_height != height) {
        stbi_image_free(pixels);
        errors_.fail(label + ": decoded size differs from the header's");
    }
    image->image.assign(pixels, pixels + size_t(texels) * 4);
    stbi_image_free(pixels);
    describe_rgba8();
}

namespace {

// sRGB transfer function, decoded once for all 256 byte values.
const float* srgb_to_linear_table() {
    static const auto table = [] {
        std::array<float, 256> t{};
        for (int i = 0; i < 256; ++i) {
            const double c = i / 255.0;
            t[size_t(i)] = float(c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4));
        }
        return t;
    }();
    return table.data();
}

}  // namespace

Texture srgb_texture(const tinygltf::Image& image, std::string name) {
    const float* linear = srgb_to_linear_table();
    Texture texture;
    texture.name = std::move(name);
    texture.width = image.width;
    texture.height = image.height;
    const size_t texels = size_t(std::max(image.width, 0)) * size_t(std::max(image.height, 0));
    if (image.image.empty() && image.component == 4) return texture;  // not decoded (LoadLimits::decode_images)
    if (image.component != 4 || image.bits != 8 || image.image.size() != texels * 4)
        throw std::logic_error("srgb_texture: image is not decoded RGBA8");
    texture.texels.resize(texels);
    const unsigned char* p = image.image.data();
    for (size_t i = 0; i < texels; ++i, p += 4)
        texture.texels[i] = glm::vec4(linear[p[0]], linear[p[1]], linear[p[2]], p[3] / 255.0f);
    return texture;
}

}  // namespace lf::gltf
