// A 64-bit hash of bytes (FNV-1a over 8-byte words, with a fold): layouts,
// checksums and a scene's content. Not cryptographic: it tells apart what
// changed by accident, never what was made to collide.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

namespace lf {

inline constexpr uint64_t kHashSeed = 0xcbf29ce484222325ull;

inline uint64_t hash_bytes(const void* data, size_t bytes, uint64_t seed = kHashSeed) {
    constexpr uint64_t kPrime = 0x100000001b3ull;
    const auto* p = static_cast<const unsigned char*>(data);
    uint64_t h = seed;
    size_t i = 0;
    for (; i + 8 <= bytes; i += 8) {
        uint64_t word;
        std::memcpy(&word, p + i, 8);
        h = (h ^ word) * kPrime;
        h ^= h >> 29;  // FNV's multiply only moves bits up: fold the high ones down
    }
    for (; i < bytes; ++i) h = (h ^ p[i]) * kPrime;
    return h;
}

template <class T>
uint64_t hash_vector(const std::vector<T>& v, uint64_t seed = kHashSeed) {
    return hash_bytes(v.data(), v.size() * sizeof(T), seed);
}

}  // namespace lf
