#include "scene/gltf_accessors.h"

#include <algorithm>
#include <cstring>

namespace lf::gltf {

namespace {

constexpr uint64_t kMaxCountWithoutView = uint64_t(1) << 20;

int component_size(int component_type) {
    switch (component_type) {
    case TINYGLTF_COMPONENT_TYPE_BYTE:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return 1;
    case TINYGLTF_COMPONENT_TYPE_SHORT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: return 2;
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
    case TINYGLTF_COMPONENT_TYPE_FLOAT: return 4;
    default: return 0;  // INT and DOUBLE are not glTF 2.0 component types
    }
}

int component_count(int type) {
    switch (type) {
    case TINYGLTF_TYPE_SCALAR: return 1;
    case TINYGLTF_TYPE_VEC2: return 2;
    case TINYGLTF_TYPE_VEC3: return 3;
    case TINYGLTF_TYPE_VEC4: return 4;
    case TINYGLTF_TYPE_MAT2: return 4;
    case TINYGLTF_TYPE_MAT3: return 9;
    case TINYGLTF_TYPE_MAT4: return 16;
    default: return 0;
    }
}

// a + b and a * b, false on 64-bit overflow.
bool add(uint64_t a, uint64_t b, uint64_t* r) { return !__builtin_add_overflow(a, b, r); }
bool mul(uint64_t a, uint64_t b, uint64_t* r) { return !__builtin_mul_overflow(a, b, r); }

template <typename T>
T load(const unsigned char* p) {
    T v;
    std::memcpy(&v, p, sizeof(T));
    return v;
}

}  // namespace

std::string component_type_name(int component_type) {
    switch (component_type) {
    case TINYGLTF_COMPONENT_TYPE_BYTE: return "BYTE";
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: return "UNSIGNED_BYTE";
    case TINYGLTF_COMPONENT_TYPE_SHORT: return "SHORT";
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: return "UNSIGNED_SHORT";
    case TINYGLTF_COMPONENT_TYPE_INT: return "INT";
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: return "UNSIGNED_INT";
    case TINYGLTF_COMPONENT_TYPE_FLOAT: return "FLOAT";
    default: return "component type " + std::to_string(component_type);
    }
}

std::string accessor_type_name(int type) {
    switch (type) {
    case TINYGLTF_TYPE_SCALAR: return "SCALAR";
    case TINYGLTF_TYPE_VEC2: return "VEC2";
    case TINYGLTF_TYPE_VEC3: return "VEC3";
    case TINYGLTF_TYPE_VEC4: return "VEC4";
    case TINYGLTF_TYPE_MAT2: return "MAT2";
    case TINYGLTF_TYPE_MAT3: return "MAT3";
    case TINYGLTF_TYPE_MAT4: return "MAT4";
    default: return "type " + std::to_string(type);
    }
}

AccessorReader::AccessorReader(const tinygltf::Model& model, const Errors& errors, uint64_t max_count)
    : model_(model), errors_(errors), max_count_(max_count) {}

void AccessorReader::check_buffer_views() const {
    for (size_t i = 0; i < model_.bufferViews.size(); ++i) {
        const tinygltf::BufferView& view = model_.bufferViews[i];
        if (view.buffer < 0 || size_t(view.buffer) >= model_.buffers.size())
            errors_.fail("bufferView", int64_t(i), "buffer " + std::to_string(view.buffer) + " does not exist");
        const uint64_t buffer_size = model_.buffers[size_t(view.buffer)].data.size();
        uint64_t end = 0;
        if (!add(view.byteOffset, view.byteLength, &end) || end > buffer_size) {
            errors_.fail("bufferView", int64_t(i),
                         "byteOffset " + std::to_string(view.byteOffset) + " + byteLength " +
                             std::to_string(view.byteLength) + " exceeds buffer " + std::to_string(view.buffer) +
                             " length " + std::to_string(buffer_size));
        }
    }
}

const unsigned char* AccessorReader::view_data(int view, size_t* size) const {
    const tinygltf::BufferView& v = model_.bufferViews.at(size_t(view));
    *size = v.byteLength;
    return model_.buffers[size_t(v.buffer)].data.data() + v.byteOffset;
}

const tinygltf::Accessor& AccessorReader::accessor(int index) const {
    if (index < 0 || size_t(index) >= model_.accessors.size()) {
        errors_.fail("accessor", index,
                     "does not exist (the file has " + std::to_string(model_.accessors.size()) + " accessors)");
    }
    return model_.accessors[size_t(index)];
}

size_t AccessorReader::count(int index) const { return accessor(index).count; }

void AccessorReader::check_view_range(int view, uint64_t offset, uint64_t count, uint64_t stride, uint64_t element_size,
                                      const std::string& where) const {
    if (view < 0 || size_t(view) >= model_.bufferViews.size())
        errors_.fail(where + ": bufferView " + std::to_string(view) + " does not exist");
    const tinygltf::BufferView& v = model_.bufferViews[size_t(view)];
    // The last element ends at offset + (count-1)*stride + element_size.
    uint64_t span = 0, end = 0;
    const bool fits_64_bits =
        count > 0 && mul(count - 1, stride, &span) && add(span, element_size, &end) && add(end, offset, &end);
    if (!fits_64_bits || end > v.byteLength) {
        const std::string need = fits_64_bits ? std::to_string(end) : "over 2^64";
        errors_.fail(where + ": byteOffset+length " + need + " exceeds bufferView " + std::to_string(view) +
                     " length " + std::to_string(v.byteLength) + " (count " + std::to_string(count) + ", stride " +
                     std::to_string(stride) + ")");
    }
}

const unsigned char* AccessorReader::view_base(int view) const {
    const tinygltf::BufferView& v = model_.bufferViews[size_t(view)];
    return model_.buffers[size_t(v.buffer)].data.data() + v.byteOffset;
}

AccessorReader::Elements AccessorReader::elements(int index) const {
    const tinygltf::Accessor& a = accessor(index);
    const std::string where = "accessor " + std::to_string(index);
    const uint64_t element_size = uint64_t(component_size(a.componentType)) * uint64_t(component_count(a.type));
    if (element_size == 0)
        errors_.fail(where + ": " + component_type_name(a.componentType) + " " + accessor_type_name(a.type) +
                     " is not readable");
    const uint64_t count = a.count;
    if (count == 0) errors_.fail(where + ": count is 0");

    uint64_t stride = element_size;
    if (a.bufferView >= 0) {
        if (size_t(a.bufferView) >= model_.bufferViews.size())
            errors_.fail(where + ": bufferView " + std::to_string(a.bufferView) + " does not exist");
        const tinygltf::BufferView& view = model_.bufferViews[size_t(a.bufferView)];
        if (view.byteStride != 0) stride = view.byteStride;
        if (stride < element_size) {
            errors_.fail(where + ": bufferView " + std::to_string(a.bufferView) + " byteStride " +
                         std::to_string(stride) + " is smaller than the element size " + std::to_string(element_size));
        }
        check_view_range(a.bufferView, a.byteOffset, count, stride, element_size, where);
    }
    // An accessor without a bufferView is zeros plus sparse values: legitimate,
    // but never large in practice, and a cheap way to ask for a huge allocation.
    const uint64_t limit = a.bufferView >= 0 ? max_count_ : std::min(max_count_, kMaxCountWithoutView);
    if (count > limit) {
        errors_.fail(where + ": count " + std::to_string(count) + " exceeds the limit of " + std::to_string(limit) +
                     " elements" + (a.bufferView >= 0 ? "" : " for an accessor without a bufferView"));
    }

    Elements e;
    e.count = count;
    if (a.bufferView >= 0 && !a.sparse.isSparse) {
        // The common case: read in place from the checked view.
        e.base = view_base(a.bufferView) + a.byteOffset;
        e.stride = stride;
        return e;
    }
    // Zeros where there is no bufferView (glTF 2.0 §3.6.2.3), then the sparse values on top.
    e.storage.assign(size_t(count * element_size), 0);
    if (a.bufferView >= 0) {
        const unsigned char* base = view_base(a.bufferView) + a.byteOffset;
        for (uint64_t i = 0; i < count; ++i)
            std::memcpy(e.storage.data() + i * element_size, base + i * stride, size_t(element_size));
    }
    if (a.sparse.isSparse) apply_sparse(index, e.storage.data(), element_size);
    e.stride = element_size;
    return e;
}

void AccessorReader::apply_sparse(int index, unsigned char* data, uint64_t element_size) const {
    const tinygltf::Accessor& a = model_.accessors[size_t(index)];
    const std::string where = "accessor " + std::to_string(index) + " sparse";
    if (a.sparse.count <= 0 || uint64_t(a.sparse.count) > a.count) {
        errors_.fail(where + ": count " + std::to_string(a.sparse.count) + " is not in [1, " + std::to_string(a.count) +
                     "]");
    }
    if (a.sparse.indices.byteOffset < 0 || a.sparse.values.byteOffset < 0)
        errors_.fail(where + ": negative byteOffset");
    const uint64_t n = uint64_t(a.sparse.count);
    const int index_type = a.sparse.indices.componentType;
    const uint64_t index_size = uint64_t(component_size(index_type));
    if (index_type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE && index_type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
        index_type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT) {
        errors_.fail(where + ": indices componentType " + component_type_name(index_type) +
                     " is not an unsigned integer type");
    }

    // Both arrays are tightly packed.
    check_view_range(a.sparse.indices.bufferView, uint64_t(a.sparse.indices.byteOffset), n, index_size, index_size,
                     where + " indices");
    check_view_range(a.sparse.values.bufferView, uint64_t(a.sparse.values.byteOffset), n, element_size, element_size,
                     where + " values");
    const unsigned char* indices = view_base(a.sparse.indices.bufferView) + a.sparse.indices.byteOffset;
    const unsigned char* values = view_base(a.sparse.values.bufferView) + a.sparse.values.byteOffset;

    uint64_t previous = 0;
    for (uint64_t k = 0; k < n; ++k) {
        const unsigned char* p = indices + k * index_size;
        const uint64_t target = index_size == 1   ? load<uint8_t>(p)
                                : index_size == 2 ? load<uint16_t>(p)
                                                  : load<uint32_t>(p);
        if (target >= a.count) {
            errors_.fail(where + ": index " + std::to_string(target) + " (entry " + std::to_string(k) +
                         ") is out of range for count " + std::to_string(a.count));
        }
        if (k > 0 && target <= previous)
            errors_.fail(where + ": indices are not strictly increasing at entry " + std::to_string(k));
        previous = target;
        std::memcpy(data + target * element_size, values + k * element_size, size_t(element_size));
    }
}

std::vector<glm::vec3> AccessorReader::read_vec3(int index, std::string_view semantic) const {
    const tinygltf::Accessor& a = accessor(index);
    if (a.type != TINYGLTF_TYPE_VEC3 || a.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT) {
        errors_.fail("accessor", index,
                     std::string(semantic) + " must be VEC3 FLOAT, not " + accessor_type_name(a.type) + " " +
                         component_type_name(a.componentType));
    }
    const Elements e = elements(index);
    std::vector<glm::vec3> out;
    out.reserve(size_t(e.count));
    for (uint64_t i = 0; i < e.count; ++i) {
        const unsigned char* p = e.at(i);
        out.emplace_back(load<float>(p), load<float>(p + 4), load<float>(p + 8));
    }
    return out;
}

std::vector<glm::vec2> AccessorReader::read_vec2(int index, std::string_view semantic) const {
    const tinygltf::Accessor& a = accessor(index);
    const int ct = a.componentType;
    const bool normalized_int =
        a.normalized && (ct == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE || ct == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT);
    if (a.type != TINYGLTF_TYPE_VEC2 || !(ct == TINYGLTF_COMPONENT_TYPE_FLOAT || normalized_int)) {
        errors_.fail("accessor", index,
                     std::string(semantic) + " must be VEC2 FLOAT or normalized UNSIGNED_BYTE/UNSIGNED_SHORT, not " +
                         accessor_type_name(a.type) + " " + component_type_name(ct) +
                         (a.normalized ? " normalized" : ""));
    }
    const Elements e = elements(index);
    std::vector<glm::vec2> out;
    out.reserve(size_t(e.count));
    // Normalized unsigned integers map [0, max] to [0, 1] (glTF 2.0 §3.11).
    for (uint64_t i = 0; i < e.count; ++i) {
        const unsigned char* p = e.at(i);
        if (ct == TINYGLTF_COMPONENT_TYPE_FLOAT) out.emplace_back(load<float>(p), load<float>(p + 4));
        else if (ct == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE) out.push_back(glm::vec2(p[0], p[1]) / 255.0f);
        else out.push_back(glm::vec2(load<uint16_t>(p), load<uint16_t>(p + 2)) / 65535.0f);
    }
    return out;
}

std::vector<uint32_t> AccessorReader::read_indices(int index) const {
    const tinygltf::Accessor& a = accessor(index);
    const int ct = a.componentType;
    if (a.type != TINYGLTF_TYPE_SCALAR ||
        (ct != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE && ct != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
         ct != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT)) {
        errors_.fail("accessor", index,
                     "indices must be SCALAR UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT, not " +
                         accessor_type_name(a.type) + " " + component_type_name(ct));
    }
    const Elements e = elements(index);
    std::vector<uint32_t> out;
    out.reserve(size_t(e.count));
    for (uint64_t i = 0; i < e.count; ++i) {
        const unsigned char* p = e.at(i);
        if (ct == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE) out.push_back(*p);
        else if (ct == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT) out.push_back(load<uint16_t>(p));
        else out.push_back(load<uint32_t>(p));
    }
    return out;
}

}  // namespace lf::gltf
