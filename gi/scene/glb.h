// The GLB container's layout (glTF 2.0, "GLB File Format Specification"): a
// 12-byte header (magic, version, total length), then chunks of (length,
// type, data), the JSON chunk first at byte 12. Little-endian, as is every
// machine lightfarm runs on. Read by the loader (gltf_container.cpp),
// rewritten by the glb writer (lightmapped_gltf.cpp).
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>

namespace lf::glb {

inline constexpr uint32_t kMagic = 0x46546C67;      // "glTF"
inline constexpr uint32_t kChunkJson = 0x4E4F534A;  // "JSON"
inline constexpr uint32_t kChunkBin = 0x004E4942;   // "BIN\0"

inline uint32_t read_u32(const void* bytes, size_t at) {
    uint32_t v = 0;
    std::memcpy(&v, static_cast<const unsigned char*>(bytes) + at, 4);
    return v;
}

inline void write_u32(void* bytes, size_t at, uint32_t v) {
    std::memcpy(static_cast<unsigned char*>(bytes) + at, &v, 4);
}

}  // namespace lf::glb
