#include "sh/sh_basis.h"

#include <cmath>
#include <stdexcept>
#include <vector>

namespace lf {

ShCoefficients sh_evaluate(glm::vec3 d) {
    const float x = d.x, y = d.y, z = d.z;
    // The table of sh_basis.h, line by line.
    return {0.28209479177387814f,
            0.4886025119029199f * x,
            0.4886025119029199f * y,
            0.4886025119029199f * z,
            1.0925484305920792f * z * x,
            1.0925484305920792f * x * y,
            0.31539156525252005f * (3.0f * y * y - 1.0f),
            1.0925484305920792f * z * y,
            0.5462742152960396f * (z * z - x * x),
            0.5900435899266435f * x * (3.0f * z * z - x * x),
            2.890611442640554f * x * y * z,
            0.4570457994644658f * x * (5.0f * y * y - 1.0f),
            0.3731763325901154f * y * (5.0f * y * y - 3.0f),
            0.4570457994644658f * z * (5.0f * y * y - 1.0f),
            1.445305721320277f * y * (z * z - x * x),
            0.5900435899266435f * z * (z * z - 3.0f * x * x)};
}

double clamped_cosine_zonal(int band) {
    // z_l = 2 pi ∫_0^1 max(0, t) P_l(t) sqrt((2l+1)/(4pi)) dt.
    switch (band) {
    case 0: return std::sqrt(M_PI) / 2.0;
    case 1: return std::sqrt(M_PI / 3.0);
    case 2: return std::sqrt(5.0 * M_PI) / 8.0;
    default: return 0.0;  // odd bands above 1 vanish
    }
}

ShCoefficients unoccluded_transfer(glm::vec3 n) {
    const ShCoefficients y = sh_evaluate(glm::normalize(n));
    ShCoefficients t{};
    for (int i = 0; i < kShMaxCoefficients; ++i) {
        const int l = sh_band_of(i);
        t[i] = float(std::sqrt(4.0 * M_PI / (2.0 * l + 1.0)) * clamped_cosine_zonal(l)) * y[i];
    }
    return t;
}

namespace {

// Solves A x = b (n x n, row-major) by Gaussian elimination with partial pivoting.
std::vector<double> solve(std::vector<double> a, std::vector<double> b, int n) {
    for (int c = 0; c < n; ++c) {
        int pivot = c;
        for (int r = c + 1; r < n; ++r)
            if (std::abs(a[r * n + c]) > std::abs(a[pivot * n + c])) pivot = r;
        for (int k = 0; k < n; ++k) std::swap(a[c * n + k], a[pivot * n + k]);
        std::swap(b[c], b[pivot]);
        for (int r = c + 1; r < n; ++r) {
            const double f = a[r * n + c] / a[c * n + c];
            for (int k = c; k < n; ++k) a[r * n + k] -= f * a[c * n + k];
            b[r] -= f * b[c];
        }
    }
    std::vector<double> x(n);
    for (int r = n - 1; r >= 0; --r) {
        double s = b[r];
        for (int k = r + 1; k < n; ++k) s -= a[r * n + k] * x[k];
        x[r] = s / a[r * n + r];
    }
    return x;
}

}  // namespace

ShRotation::ShRotation(const glm::mat3& rotation) {
    // Directions well spread over the sphere (a Fibonacci lattice): many more
    // than 2l+1, so the normal equations are well conditioned.
    constexpr int kDirections = 64;
    const glm::mat3 inverse = glm::transpose(rotation);
    std::vector<ShCoefficients> y(kDirections), y_rotated(kDirections);
    for (int k = 0; k < kDirections; ++k) {
        const double v = 1.0 - (2.0 * k + 1.0) / kDirections;
        const double phi = k * M_PI * (3.0 - std::sqrt(5.0));
        const double r = std::sqrt(1.0 - v * v);
        const glm::vec3 d(float(r * std::cos(phi)), float(v), float(r * std::sin(phi)));
        y[k] = sh_evaluate(d);
        y_rotated[k] = sh_evaluate(inverse * d);
    }
    for (int l = 0; l < kShMaxBands; ++l) {
        const int n = 2 * l + 1, first = l * l;
        // Normal matrix YᵀY, shared by every column of the rotation.
        std::vector<double> normal(n * n, 0.0);
        for (int r = 0; r < n; ++r)
            for (int c = 0; c < n; ++c)
                for (int k = 0; k < kDirections; ++k) normal[r * n + c] += double(y[k][first + r]) * y[k][first + c];
        // Column c of the matrix: the rotated coefficients of basis function c.
        for (int c = 0; c < n; ++c) {
            std::vector<double> rhs(n, 0.0);
            for (int r = 0; r < n; ++r)
                for (int k = 0; k < kDirections; ++k) rhs[r] += double(y[k][first + r]) * y_rotated[k][first + c];
            const std::vector<double> column = solve(normal, rhs, n);
            for (int r = 0; r < n; ++r) m_[l][r * n + c] = float(column[r]);
        }
    }
}

ShCoefficients ShRotation::apply(const ShCoefficients& c) const {
    ShCoefficients out{};
    for (int l = 0; l < kShMaxBands; ++l) {
        const int n = 2 * l + 1, first = l * l;
        for (int r = 0; r < n; ++r) {
            float s = 0.0f;
            for (int k = 0; k < n; ++k) s += m_[l][r * n + k] * c[first + k];
            out[first + r] = s;
        }
    }
    return out;
}

ShRgb ShRotation::apply(const ShRgb& c) const {
    ShRgb out{};
    for (int channel = 0; channel < 3; ++channel) {
        ShCoefficients one{};
        for (int i = 0; i < kShMaxCoefficients; ++i) one[i] = c[i][channel];
        one = apply(one);
        for (int i = 0; i < kShMaxCoefficients; ++i) out[i][channel] = one[i];
    }
    return out;
}

const char* to_string(ShWindow w) {
    return w == ShWindow::Hanning ? "hanning" : w == ShWindow::Lanczos ? "lanczos" : "none";
}

ShWindow parse_sh_window(const std::string& text) {
    if (text == "none") return ShWindow::None;
    if (text == "hanning") return ShWindow::Hanning;
    if (text == "lanczos") return ShWindow::Lanczos;
    throw std::invalid_argument("SH window must be 'none', 'hanning' or 'lanczos', not '" + text + "'");
}

float sh_window_factor(ShWindow window, int band, int width) {
    if (window == ShWindow::None || band == 0) return 1.0f;
    if (band >= width) return 0.0f;
    const double x = M_PI * band / width;
    return float(window == ShWindow::Hanning ? 0.5 * (1.0 + std::cos(x)) : std::sin(x) / x);
}

}  // namespace lf
