// Checked reading of glTF accessors (internal to gi/scene).
//
// Nothing tinygltf parsed is trusted: every bufferView is checked against the
// bytes its buffer really holds, and every accessor read against its
// bufferView (offset, count, stride, element size, in 64-bit arithmetic with
// overflow checks) before a byte is copied. Sparse accessors are applied.
// Refusals name the accessor: "accessor 12: byteOffset+length 4096 exceeds
// bufferView 3 length 2048".
#pragma once

#include "scene/gltf_errors.h"

#include <glm/glm.hpp>
#include <tiny_gltf.h>

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace lf::gltf {

// "FLOAT", "UNSIGNED_SHORT", ...
std::string component_type_name(int component_type);
// "VEC3", ...
std::string accessor_type_name(int type);

class AccessorReader {
public:
    // max_count bounds the elements of any one accessor, so that an accessor
    // without a bufferView (all zeros, or sparse) cannot ask for a huge allocation.
    AccessorReader(const tinygltf::Model& model, const Errors& errors, uint64_t max_count);

    // Checks every bufferView against its buffer; call once before reading.
    void check_buffer_views() const;

    // The bytes of a checked bufferView (for images stored in a GLB).
    const unsigned char* view_data(int view, size_t* size) const;

    // Elements of accessor `index` after validation (for vertex counts).
    size_t count(int index) const;

    // Attribute readers; `semantic` ("POSITION", "TEXCOORD_1") goes into errors.
    // VEC3 FLOAT.
    std::vector<glm::vec3> read_vec3(int index, std::string_view semantic) const;
    // VEC2 FLOAT, or normalized UNSIGNED_BYTE / UNSIGNED_SHORT.
    std::vector<glm::vec2> read_vec2(int index, std::string_view semantic) const;
    // SCALAR UNSIGNED_BYTE / UNSIGNED_SHORT / UNSIGNED_INT.
    std::vector<uint32_t> read_indices(int index) const;

private:
    // An accessor's checked elements: in place in its bufferView, or (sparse,
    // or no bufferView) in a packed copy with the sparse values applied.
    struct Elements {
        const unsigned char* base = nullptr;
        uint64_t stride = 0;
        uint64_t count = 0;
        std::vector<unsigned char> storage;
        const unsigned char* at(uint64_t i) const { return (storage.empty() ? base : storage.data()) + i * stride; }
    };

    const tinygltf::Accessor& accessor(int index) const;
    Elements elements(int index) const;
    // Checks that `count` elements of `element_size` bytes, `stride` apart,
    // from `offset` lie inside bufferView `view`.
    void check_view_range(int view, uint64_t offset, uint64_t count, uint64_t stride, uint64_t element_size,
                          const std::string& where) const;
    // First byte of a bufferView (views were checked against their buffers).
    const unsigned char* view_base(int view) const;
    void apply_sparse(int index, unsigned char* data, uint64_t element_size) const;

    const tinygltf::Model& model_;
    const Errors& errors_;
    uint64_t max_count_;
};

}  // namespace lf::gltf
