// Real orthonormal spherical harmonics, bands l = 0..3 (16 coefficients),
// index l(l+1)+m (DESIGN.md "Conventions"; Sloan 2002, Green 2003).
//
// The basis is written directly in glTF world coordinates (y up) of a unit
// direction (x, y, z). The polar axis is +y, so the zonal (m = 0) functions
// depend on y only and a sky lit from above lives in them. There is no
// Condon-Shortley phase: every constant below is positive.
//
//   i  l  m   y_i(x, y, z)
//   0  0  0   0.282095                      = 1/(2 sqrt(pi))
//   1  1 -1   0.488603 x                    = sqrt(3/(4pi))
//   2  1  0   0.488603 y
//   3  1  1   0.488603 z
//   4  2 -2   1.092548 z x                  = sqrt(15/(4pi))
//   5  2 -1   1.092548 x y
//   6  2  0   0.315392 (3y² - 1)            = sqrt(5/(16pi))
//   7  2  1   1.092548 z y
//   8  2  2   0.546274 (z² - x²)            = sqrt(15/(16pi))
//   9  3 -3   0.590044 x (3z² - x²)         = sqrt(35/(32pi))
//  10  3 -2   2.890611 x y z                = sqrt(105/(4pi))
//  11  3 -1   0.457046 x (5y² - 1)          = sqrt(21/(32pi))
//  12  3  0   0.373176 y (5y² - 3)          = sqrt(7/(16pi))
//  13  3  1   0.457046 z (5y² - 1)
//  14  3  2   1.445306 y (z² - x²)          = sqrt(105/(16pi))
//  15  3  3   0.590044 z (z² - 3x²)
//
// These are the textbook polynomials (Sloan, "Stupid Spherical Harmonics
// Tricks", 2008, without its (-1)^m) evaluated in the right-handed frame
// X = z, Y = x, Z = y, i.e. a cyclic relabelling of the world axes, so the
// set is orthonormal and closed under rotation band by band. The same table
// is in gi/shaders/sh_basis.glsl and in the sh_transfer.bin documentation.
#pragma once

#include <glm/glm.hpp>

#include <array>
#include <string>

namespace lf {

constexpr int kShMaxBands = 4;
constexpr int kShMaxCoefficients = kShMaxBands * kShMaxBands;

using ShCoefficients = std::array<float, kShMaxCoefficients>;
using ShRgb = std::array<glm::vec3, kShMaxCoefficients>;

constexpr int sh_index(int l, int m) { return l * (l + 1) + m; }
constexpr int sh_band_of(int index) { return index < 1 ? 0 : index < 4 ? 1 : index < 9 ? 2 : 3; }

// y_0 … y_15 at unit direction d.
ShCoefficients sh_evaluate(glm::vec3 d);

// The clamped cosine max(0, cos θ) about the polar axis projected on the
// zonal harmonics: z_0 = sqrt(pi)/2, z_1 = sqrt(pi/3), z_2 = sqrt(5 pi)/8, z_3 = 0.
double clamped_cosine_zonal(int band);

// Unoccluded transfer of a surface with normal n: the clamped cosine's zonal
// harmonics rotated to n, T_lm = sqrt(4pi/(2l+1)) z_l y_lm(n) (Sloan 2002 eq. 7
// for zonal rotation). T_0 = sqrt(pi)/2; |T_band1| = 2pi/3 sqrt(3/(4pi)).
ShCoefficients unoccluded_transfer(glm::vec3 n);

// Rotation of SH coefficients: rotated(c) are the coefficients of the
// function f(R^-1 ω) when c are those of f(ω). Each band is a (2l+1)-dimensional
// space closed under rotation, so its matrix is found exactly by evaluating
// the band at enough directions ω_k and solving Y c' = Y_R c in least squares,
// Y[k][m] = y_lm(ω_k), Y_R[k][m] = y_lm(R^-1 ω_k) (the rows span the band).
class ShRotation {
public:
    explicit ShRotation(const glm::mat3& rotation);
    ShCoefficients apply(const ShCoefficients& c) const;
    ShRgb apply(const ShRgb& c) const;
    // Entry (row, column) of band l's (2l+1)x(2l+1) matrix.
    float band_matrix(int l, int row, int column) const { return m_[l][row * (2 * l + 1) + column]; }

private:
    std::array<std::array<float, 49>, kShMaxBands> m_{};
};

// Windowing against ringing (Sloan 2008 §"windowing"): band l's coefficients
// are scaled by w_l. Width = the band count in use (w_l = 0 for l >= width).
enum class ShWindow { None, Hanning, Lanczos };
const char* to_string(ShWindow w);
ShWindow parse_sh_window(const std::string& text);  // "none" | "hanning" | "lanczos"
// Hanning: (1 + cos(pi l / width)) / 2; Lanczos sigma: sin(pi l / width) / (pi l / width).
float sh_window_factor(ShWindow window, int band, int width);

}  // namespace lf
