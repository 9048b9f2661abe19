// Image decoding for the glTF loader (internal to gi/scene).
//
// tinygltf hands every image's encoded bytes to a loader callback. Ours reads
// the image header first (stbi_info_from_memory) and refuses an image whose
// width or height exceeds LoadLimits::max_texture_dim, or whose texels would
// overrun the scene's texel budget, before a single pixel is allocated: a
// 100-byte PNG can claim 65535 x 65535 (16 GiB of RGBA). Only PNG and JPEG
// (glTF's two image formats) are decoded.
#pragma once

#include "scene/gltf_errors.h"
#include "scene/scene.h"

#include <tiny_gltf.h>

#include <cstdint>
#include <string>
#include <vector>

namespace lf::gltf {

class ImageDecoder {
public:
    // `used[i]`: image i feeds a texture the Scene keeps (base colour or
    // emission); other images are not decoded at all.
    ImageDecoder(const Errors& errors, const LoadLimits& limits, std::vector<bool> used);

    // For tinygltf::TinyGLTF::SetImageLoader(&ImageDecoder::callback, this).
    // Images stored in a bufferView are left for decode_buffer_view_image():
    // tinygltf does not check that the view lies inside its buffer.
    static bool callback(tinygltf::Image* image, const int image_index, std::string* err, std::string* warn,
                         int req_width, int req_height, const unsigned char* bytes, int size, void* self);

    // Decodes image `index` from bytes already checked to lie inside the file
    // into image->image (RGBA8). Throws SceneError naming the image.
    void decode(tinygltf::Image* image, int index, const unsigned char* bytes, size_t size);

    bool is_used(int index) const { return index >= 0 && size_t(index) < used_.size() && used_[size_t(index)]; }

    // The one-line message of a refusal inside callback(), for the caller to
    // throw once tinygltf has returned (its own message is multi-line and vaguer).
    const std::string& deferred_error() const { return deferred_error_; }

private:
    void check_dimensions(const std::string& label, uint32_t width, uint32_t height) const;

    const Errors& errors_;
    const LoadLimits& limits_;
    std::vector<bool> used_;
    uint64_t texels_left_;
    std::string deferred_error_;
};

// An RGBA8 image as a linear float Texture: colour channels decoded from
// sRGB (glTF's base colour and emissive textures are sRGB), alpha linear.
Texture srgb_texture(const tinygltf::Image& image, std::string name);

}  // namespace lf::gltf
