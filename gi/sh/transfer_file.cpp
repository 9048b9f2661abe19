#include "sh/transfer_file.h"

#include "io/image_files.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace lf {

namespace {

constexpr char kMagic[8] = {'L', 'F', 'S', 'H', 'T', 'R', 'F', '\0'};
constexpr uint32_t kVersion = 1;
constexpr size_t kHeaderBytes = 32, kPrimitiveBytes = 16;

// Little-endian regardless of the host.
void put_u32(std::string& out, uint32_t v) {
    for (int k = 0; k < 4; ++k) out.push_back(char((v >> (8 * k)) & 0xffu));
}
uint32_t get_u32(const std::string& in, size_t at) {
    uint32_t v = 0;
    for (int k = 0; k < 4; ++k) v |= uint32_t(uint8_t(in[at + size_t(k)])) << (8 * k);
    return v;
}
uint32_t float_bits(float f) {
    uint32_t u;
    std::memcpy(&u, &f, 4);
    return u;
}
float bits_float(uint32_t u) {
    float f;
    std::memcpy(&f, &u, 4);
    return f;
}

}  // namespace

uint16_t float_to_half(float f) {
    const uint32_t x = float_bits(f);
    const uint32_t sign = (x >> 16) & 0x8000u;
    const uint32_t abs = x & 0x7fffffffu;
    if (abs >= 0x7f800000u) return uint16_t(sign | 0x7c00u | (abs > 0x7f800000u ? 0x200u : 0u));  // inf, nan
    if (abs >= 0x477ff000u) return uint16_t(sign | 0x7c00u);  // rounds beyond 65504: inf
    if (abs < 0x38800000u) {
        // Subnormal half (or zero): value / 2^-24, rounded to nearest even.
        const float scaled = bits_float(abs) * 16777216.0f;
        return uint16_t(sign | uint32_t(std::nearbyint(scaled)));
    }
    // Normal: rebias the exponent, round the mantissa to 10 bits (nearest even).
    const uint32_t rounded = abs + 0xfffu + ((abs >> 13) & 1u);
    return uint16_t(sign | ((rounded - 0x38000000u) >> 13));
}

float half_to_float(uint16_t h) {
    const uint32_t sign = uint32_t(h & 0x8000u) << 16;
    const uint32_t exponent = (h >> 10) & 0x1fu, mantissa = h & 0x3ffu;
    if (exponent == 0) return bits_float(sign) + (sign ? -1.0f : 1.0f) * float(mantissa) / 16777216.0f;
    if (exponent == 31) return bits_float(sign | 0x7f800000u | (mantissa << 13));
    return bits_float(sign | ((exponent + 112u) << 23) | (mantissa << 13));
}

ShTransferFile transfer_by_primitive(const Scene& scene, const std::vector<ShCoefficients>& per_vertex, int bands,
                                     int bounces) {
    if (per_vertex.size() != scene.positions.size())
        throw std::invalid_argument("transfer for " + std::to_string(per_vertex.size()) + " vertices, scene has " +
                                    std::to_string(scene.positions.size()));
    ShTransferFile file;
    file.bands = bands;
    file.bounces = bounces;
    for (const PrimitiveInstance& inst : scene.instances) {
        ShTransferFile::Primitive p;
        p.node = inst.node;
        p.mesh = inst.mesh;
        p.primitive = inst.primitive;
        auto source = [&](uint32_t k) {
            return scene.source_vertex.empty() ? k : scene.source_vertex[inst.first_vertex + k];
        };
        uint32_t count = 0;
        for (uint32_t k = 0; k < inst.vertex_count; ++k) count = std::max(count, source(k) + 1);
        p.vertices.assign(count, ShCoefficients{});
        for (uint32_t k = 0; k < inst.vertex_count; ++k) {
            ShCoefficients c = per_vertex[inst.first_vertex + k];
            std::fill(c.begin() + bands * bands, c.end(), 0.0f);
            p.vertices[source(k)] = c;  // split copies share position and normal, so any copy will do
        }
        file.primitives.push_back(std::move(p));
    }
    return file;
}

std::string encode_sh_transfer(const ShTransferFile& file, ShEncoding encoding) {
    if (file.bands < 1 || file.bands > kShMaxBands) throw std::invalid_argument("sh_transfer: bands must be 1..4");
    size_t vertices = 0;
    for (const auto& p : file.primitives) vertices += p.vertices.size();
    const size_t c = size_t(file.bands * file.bands), value_bytes = encoding == ShEncoding::Float16 ? 2 : 4;
    std::string out(kMagic, sizeof kMagic);
    out.reserve(kHeaderBytes + file.primitives.size() * kPrimitiveBytes + vertices * c * value_bytes);
    put_u32(out, kVersion);
    put_u32(out, uint32_t(file.bands));
    put_u32(out, uint32_t(file.bounces));
    put_u32(out, uint32_t(encoding));
    put_u32(out, uint32_t(file.primitives.size()));
    put_u32(out, uint32_t(vertices));
    for (const auto& p : file.primitives) {
        put_u32(out, uint32_t(p.node));
        put_u32(out, uint32_t(p.mesh));
        put_u32(out, uint32_t(p.primitive));
        put_u32(out, uint32_t(p.vertices.size()));
    }
    for (const auto& p : file.primitives)
        for (const ShCoefficients& v : p.vertices)
            for (size_t i = 0; i < c; ++i) {
                if (encoding == ShEncoding::Float16) {
                    const uint16_t h = float_to_half(v[i]);
                    out.push_back(char(h & 0xffu));
                    out.push_back(char(h >> 8));
                } else {
                    put_u32(out, float_bits(v[i]));
                }
            }
    return out;
}

ShTransferFile decode_sh_transfer(const std::string& bytes, const std::string& what) {
    auto bad = [&](const std::string& why) {
        return std::runtime_error(what + ": not a valid sh_transfer file: " + why);
    };
    if (bytes.size() < kHeaderBytes || std::memcmp(bytes.data(), kMagic, sizeof kMagic) != 0) throw bad("bad magic");
    if (get_u32(bytes, 8) != kVersion) throw bad("version " + std::to_string(get_u32(bytes, 8)) + " (expected 1)");
    ShTransferFile file;
    file.bands = int(get_u32(bytes, 12));
    file.bounces = int(get_u32(bytes, 16));
    const uint32_t encoding = get_u32(bytes, 20);
    const uint64_t primitives = get_u32(bytes, 24), vertices = get_u32(bytes, 28);
    if (file.bands < 1 || file.bands > kShMaxBands) throw bad("bands " + std::to_string(file.bands));
    if (encoding > 1) throw bad("encoding " + std::to_string(encoding));
    const uint64_t c = uint64_t(file.bands * file.bands), value_bytes = encoding == 1 ? 2 : 4;
    const uint64_t expected = kHeaderBytes + primitives * kPrimitiveBytes + vertices * c * value_bytes;
    if (bytes.size() != expected)
        throw bad(std::to_string(bytes.size()) + " bytes, the header implies " + std::to_string(expected));
    size_t at = kHeaderBytes;
    uint64_t counted = 0;
    for (uint64_t k = 0; k < primitives; ++k, at += kPrimitiveBytes) {
        ShTransferFile::Primitive p;
        p.node = int(get_u32(bytes, at));
        p.mesh = int(get_u32(bytes, at + 4));
        p.primitive = int(get_u32(bytes, at + 8));
        const uint32_t n = get_u32(bytes, at + 12);
        counted += n;
        if (counted > vertices) throw bad("primitive vertex counts exceed the header's total");
        p.vertices.resize(n);
        file.primitives.push_back(std::move(p));
    }
    if (counted != vertices) throw bad("primitive vertex counts do not add up to the header's total");
    for (auto& p : file.primitives)
        for (ShCoefficients& v : p.vertices) {
            v.fill(0.0f);
            for (uint64_t i = 0; i < c; ++i) {
                if (encoding == 1) {
                    v[i] = half_to_float(uint16_t(uint8_t(bytes[at]) | (uint8_t(bytes[at + 1]) << 8)));
                    at += 2;
                } else {
                    v[i] = bits_float(get_u32(bytes, at));
                    at += 4;
                }
            }
        }
    return file;
}

void write_sh_transfer(const std::filesystem::path& path, const ShTransferFile& file, ShEncoding encoding) {
    write_file_atomic(path, encode_sh_transfer(file, encoding));
}

ShTransferFile read_sh_transfer(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error(path.string() + ": cannot open");
    std::ostringstream bytes;
    bytes << in.rdbuf();
    return decode_sh_transfer(bytes.str(), path.string());
}

}  // namespace lf
