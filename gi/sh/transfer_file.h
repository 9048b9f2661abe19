// sh_transfer.bin: per-vertex SH transfer coefficients by glTF primitive.
//
// Little-endian throughout. Header (32 bytes):
//   offset  0  char[8]  magic "LFSHTRF" followed by a zero byte
//           8  u32      version = 1
//          12  u32      bands B (1..4); C = B² coefficients per vertex
//          16  u32      bounces (0 = shadowed transfer; N = N interreflection bounces added)
//          20  u32      encoding: 0 = float32, 1 = float16 (IEEE 754 binary16, round to nearest)
//          24  u32      P = primitive count
//          28  u32      V = vertex count over all primitives
// Primitive table, P entries of 16 bytes:
//   i32 glTF node, i32 glTF mesh, i32 primitive index within the mesh, u32 vertex count
//   (vertex k is the glTF primitive's vertex k; a mesh used by several nodes
//   has one entry per node, since transfer is in world space).
// Coefficients: for each primitive in table order, for each vertex, C values
// in the order i = l(l+1)+m (4 or 2 bytes each).
//
// T_i = ∫ V(x,ω) max(0, n·ω) y_i(ω) dω (+ bounces), no albedo, no 1/pi;
// irradiance E = Σ T_i L_i with L_i from env_sh.json. Basis y_i (real,
// orthonormal, glTF world axes, y up, no Condon-Shortley phase):
//   y0 = 0.282095
//   y1 = 0.488603 x   y2 = 0.488603 y   y3 = 0.488603 z
//   y4 = 1.092548 zx  y5 = 1.092548 xy  y6 = 0.315392 (3y²-1)  y7 = 1.092548 zy  y8 = 0.546274 (z²-x²)
//   y9 = 0.590044 x(3z²-x²)  y10 = 2.890611 xyz  y11 = 0.457046 x(5y²-1)  y12 = 0.373176 y(5y²-3)
//   y13 = 0.457046 z(5y²-1)  y14 = 1.445306 y(z²-x²)  y15 = 0.590044 z(z²-3x²)
#pragma once

#include "scene/scene.h"
#include "sh/sh_basis.h"

#include <filesystem>
#include <string>
#include <vector>

namespace lf {

struct ShVertexTransfer;

enum class ShEncoding : uint32_t { Float32 = 0, Float16 = 1 };

struct ShTransferFile {
    int bands = kShMaxBands;
    int bounces = 0;
    struct Primitive {
        int node = -1, mesh = -1, primitive = -1;
        std::vector<ShCoefficients> vertices;  // coefficients >= bands² are zero
    };
    std::vector<Primitive> primitives;
};

// The baked transfer arranged by the scene's primitive instances, in glTF
// vertex order (through Scene::source_vertex when an atlas split vertices),
// truncated to `bands`.
ShTransferFile transfer_by_primitive(const Scene& scene, const std::vector<ShCoefficients>& per_vertex, int bands,
                                     int bounces);

std::string encode_sh_transfer(const ShTransferFile& file, ShEncoding encoding);
// Throws std::runtime_error naming `what` (a file name) and the problem.
ShTransferFile decode_sh_transfer(const std::string& bytes, const std::string& what);

void write_sh_transfer(const std::filesystem::path& path, const ShTransferFile& file, ShEncoding encoding);
ShTransferFile read_sh_transfer(const std::filesystem::path& path);

uint16_t float_to_half(float f);
float half_to_float(uint16_t h);

}  // namespace lf
