#include "sh/environment.h"

#include "io/image_files.h"

// stb_image from Debian's libstb-dev, compiled here as a private (static)
// copy with only the Radiance .hdr decoder, as gi/scene/gltf_images.cpp
// does for PNG/JPEG: no other decoder is reachable from an environment file.
#define STB_IMAGE_STATIC
#define STB_IMAGE_IMPLEMENTATION
#define STBI_ONLY_HDR
#if defined(__GNUC__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wsign-compare"
#endif
#include <stb/stb_image.h>
#if defined(__GNUC__)
#pragma GCC diagnostic pop
#endif

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace lf {

namespace fs = std::filesystem;

glm::vec3 equirect_direction(float u, float v) {
    const float theta = float(M_PI) * v, phi = 2.0f * float(M_PI) * (u - 0.5f);
    return {std::sin(theta) * std::cos(phi), std::cos(theta), std::sin(theta) * std::sin(phi)};
}

glm::vec2 equirect_uv(glm::vec3 d) {
    d = glm::normalize(d);
    return {0.5f + std::atan2(d.z, d.x) / (2.0f * float(M_PI)), std::acos(std::clamp(d.y, -1.0f, 1.0f)) / float(M_PI)};
}

glm::vec3 Environment::radiance(glm::vec3 direction) const {
    if (is_constant()) return constant;
    const glm::vec2 uv = equirect_uv(direction);
    const int x = std::clamp(int(uv.x * float(width)), 0, width - 1);
    const int y = std::clamp(int(uv.y * float(height)), 0, height - 1);
    return texels[size_t(y) * size_t(width) + size_t(x)];
}

namespace {

// "R,G,B": three numbers and nothing else.
bool parse_colour(const std::string& spec, glm::vec3& out) {
    std::istringstream in(spec);
    char c1 = 0, c2 = 0;
    if (!(in >> out.r >> c1 >> out.g >> c2 >> out.b) || c1 != ',' || c2 != ',') return false;
    in >> std::ws;
    return in.eof();
}

void check_texels(const Environment& env) {
    for (const glm::vec3& t : env.texels)
        if (!std::isfinite(t.r) || !std::isfinite(t.g) || !std::isfinite(t.b) || t.r < 0 || t.g < 0 || t.b < 0)
            throw std::runtime_error(env.source + ": environment has negative or non-finite radiance");
}

}  // namespace

Environment load_environment(const std::string& spec) {
    Environment env;
    env.source = spec;
    glm::vec3 colour;
    if (parse_colour(spec, colour)) {
        if (colour.r < 0 || colour.g < 0 || colour.b < 0 || !std::isfinite(colour.r + colour.g + colour.b))
            throw std::runtime_error("environment colour '" + spec + "' must be three finite non-negative numbers");
        env.constant = colour;
        return env;
    }
    const fs::path path(spec);
    if (!fs::is_regular_file(path))
        throw std::runtime_error(spec + ": environment is neither \"R,G,B\" nor a readable file");
    std::string ext = path.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    if (ext == ".exr") {
        const FloatImage image = read_exr(path);
        for (const char* c : {"R", "G", "B"})
            if (!image.channels.count(c)) throw std::runtime_error(spec + ": EXR environment has no channel " + c);
        env.width = image.width;
        env.height = image.height;
        const auto &r = image.at("R"), &g = image.at("G"), &b = image.at("B");
        env.texels.resize(r.size());
        for (size_t i = 0; i < r.size(); ++i) env.texels[i] = {r[i], g[i], b[i]};
    } else if (ext == ".hdr") {
        int w = 0, h = 0, n = 0;
        float* data = stbi_loadf(spec.c_str(), &w, &h, &n, 3);
        if (!data) throw std::runtime_error(spec + ": reading HDR failed: " + stbi_failure_reason());
        env.width = w;
        env.height = h;
        env.texels.resize(size_t(w) * size_t(h));
        for (size_t i = 0; i < env.texels.size(); ++i) env.texels[i] = {data[3 * i], data[3 * i + 1], data[3 * i + 2]};
        stbi_image_free(data);
    } else {
        throw std::runtime_error(spec + ": environment must be .exr, .hdr or \"R,G,B\"");
    }
    if (env.width < 2 || env.height < 1)
        throw std::runtime_error(spec + ": environment image is " + std::to_string(env.width) + "x" +
                                 std::to_string(env.height) + ", too small for an equirectangular map");
    check_texels(env);
    return env;
}

Environment environment_from_function(int width, int height, const std::function<glm::vec3(glm::vec3)>& radiance,
                                      const std::string& source) {
    Environment env;
    env.source = source;
    env.width = width;
    env.height = height;
    env.texels.resize(size_t(width) * size_t(height));
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x)
            env.texels[size_t(y) * size_t(width) + size_t(x)] =
                radiance(equirect_direction((float(x) + 0.5f) / float(width), (float(y) + 0.5f) / float(height)));
    return env;
}

Environment uniform_sky(int width, int height) {
    return environment_from_function(
        width, height, [](glm::vec3 d) { return glm::vec3(d.y > 0.0f ? 1.0f : 0.0f); },
        "uniform sky (1 above the horizon, 0 below)");
}

EnvironmentSh project_environment(const Environment& env, ShWindow window, int bands) {
    if (bands < 1 || bands > kShMaxBands) throw std::invalid_argument("SH bands must be 1..4");
    EnvironmentSh sh;
    sh.source = env.source;
    sh.bands = bands;
    sh.window = window;
    std::array<glm::dvec3, kShMaxCoefficients> sum{};
    if (env.is_constant()) {
        sum[0] = glm::dvec3(env.constant) * (2.0 * std::sqrt(M_PI));  // ∫ c y_0 dω = 4pi c / (2 sqrt(pi))
    } else {
        const double dphi = 2.0 * M_PI / env.width;
        for (int y = 0; y < env.height; ++y) {
            // Exact solid angle of a texel in this row (seed §2.3 weighs samples
            // uniformly on the sphere; an equirectangular row does not).
            const double d_omega = dphi * (std::cos(M_PI * y / env.height) - std::cos(M_PI * (y + 1) / env.height));
            for (int x = 0; x < env.width; ++x) {
                const glm::vec3 d =
                    equirect_direction((float(x) + 0.5f) / float(env.width), (float(y) + 0.5f) / float(env.height));
                const ShCoefficients basis = sh_evaluate(d);
                const glm::dvec3 l = glm::dvec3(env.texels[size_t(y) * size_t(env.width) + size_t(x)]) * d_omega;
                for (int i = 0; i < kShMaxCoefficients; ++i) sum[i] += l * double(basis[i]);
            }
        }
    }
    for (int l = 0; l < kShMaxBands; ++l) {
        sh.window_factor[l] = l < bands ? sh_window_factor(window, l, bands) : 0.0f;
        for (int i = l * l; i < (l + 1) * (l + 1); ++i) sh.coefficients[i] = glm::vec3(sum[i]) * sh.window_factor[l];
    }
    return sh;
}

EnvironmentSh rotate(const EnvironmentSh& sh, const glm::mat3& rotation) {
    EnvironmentSh out = sh;
    out.coefficients = ShRotation(rotation).apply(sh.coefficients);
    return out;
}

nlohmann::json to_json(const EnvironmentSh& sh) {
    nlohmann::json coefficients = nlohmann::json::array();
    for (const glm::vec3& c : sh.coefficients) coefficients.push_back({c.r, c.g, c.b});
    return {
        {"format", "lightfarm.env_sh"},
        {"version", 1},
        {"basis",
         "real orthonormal SH, index l(l+1)+m, y up, no Condon-Shortley phase; y_1 = 0.488603 (x, y, z) "
         "for i = 1, 2, 3 (full table in sh_transfer.bin's documentation, gi/sh/transfer_file.h)"},
        {"equirect",
         "theta = pi v from +y (top row up), phi = 2 pi (u - 0.5), d = (sin theta cos phi, cos theta, "
         "sin theta sin phi)"},
        {"units", "L_i = integral of radiance W/(sr m^2) x y_i over the sphere; irradiance E = sum T_i L_i (W/m^2)"},
        {"source", sh.source},
        {"bands", sh.bands},
        {"window",
         {{"kind", to_string(sh.window)},
          {"factors", {sh.window_factor[0], sh.window_factor[1], sh.window_factor[2], sh.window_factor[3]}}}},
        {"coefficients", coefficients},
    };
}

EnvironmentSh environment_sh_from_json(const nlohmann::json& j) {
    if (j.value("format", "") != "lightfarm.env_sh") throw std::runtime_error("not an env_sh.json (format field)");
    if (j.value("version", 0) != 1) throw std::runtime_error("env_sh.json: unsupported version");
    EnvironmentSh sh;
    sh.source = j.value("source", "");
    sh.bands = j.value("bands", kShMaxBands);
    const auto& c = j.at("coefficients");
    if (!c.is_array() || c.size() != size_t(kShMaxCoefficients))
        throw std::runtime_error("env_sh.json: coefficients must be 16 [r, g, b] triples");
    for (int i = 0; i < kShMaxCoefficients; ++i)
        sh.coefficients[i] = {c[i].at(0).get<float>(), c[i].at(1).get<float>(), c[i].at(2).get<float>()};
    if (j.contains("window")) {
        sh.window = parse_sh_window(j["window"].value("kind", "none"));
        for (int l = 0; l < kShMaxBands; ++l) sh.window_factor[l] = j["window"]["factors"].at(l).get<float>();
    }
    return sh;
}

EnvironmentSh load_environment_sh(const std::string& spec, ShWindow window) {
    if (spec.size() > 5 && spec.substr(spec.size() - 5) == ".json") {
        std::ifstream in(spec);
        if (!in) throw std::runtime_error(spec + ": cannot open");
        try {
            return environment_sh_from_json(nlohmann::json::parse(in));
        } catch (const std::exception& e) {
            throw std::runtime_error(spec + ": " + e.what());
        }
    }
    return project_environment(load_environment(spec), window);
}

}  // namespace lf
