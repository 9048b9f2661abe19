// Environment light for SH shading (seed §2.3): an equirectangular radiance
// map (.exr, .hdr) or a constant colour, and its projection on the 16 SH
// basis functions of sh_basis.h.
//
// Equirectangular convention (y up, as glTF): pixel column u in [0,1) from
// the left, row v in [0,1) from the top; the top row looks up (+y).
//   theta = pi v (from +y),  phi = 2 pi (u - 0.5)
//   d = (sin theta cos phi, cos theta, sin theta sin phi)
// so the image centre looks along +x and u = 0.5 + atan2(d.z, d.x) / (2 pi).
#pragma once

#include "sh/sh_basis.h"

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace lf {

struct Environment {
    std::string source;  // file name or "R,G,B", for messages and env_sh.json
    // A constant environment has width = height = 0 and `constant` set.
    glm::vec3 constant{0.0f};
    int width = 0, height = 0;
    std::vector<glm::vec3> texels;  // rows from the top, linear radiance W/(sr·m²)

    bool is_constant() const { return width == 0; }
    glm::vec3 radiance(glm::vec3 direction) const;  // nearest texel
};

glm::vec3 equirect_direction(float u, float v);
glm::vec2 equirect_uv(glm::vec3 direction);

// "R,G,B" (three numbers) is a constant colour; anything else a file:
// .exr (its R, G, B channels) or .hdr (Radiance RGBE). Throws
// std::runtime_error naming the file and what is wrong.
Environment load_environment(const std::string& spec);

// An environment sampled from a function of direction at width x height (tests, skies).
Environment environment_from_function(int width, int height, const std::function<glm::vec3(glm::vec3)>& radiance,
                                      const std::string& source);

// The SH coefficients of an environment, with the window that was applied.
struct EnvironmentSh {
    std::string source;
    ShRgb coefficients{};  // L_i, RGB; E = Σ T_i L_i is irradiance in W/m²
    int bands = kShMaxBands;
    ShWindow window = ShWindow::None;
    float window_factor[kShMaxBands] = {1, 1, 1, 1};
};

// L_i = ∫ L(ω) y_i(ω) dω over the sphere: a sum over texels with each
// texel's exact solid angle (2pi/W)(cos θ_top - cos θ_bottom), which sums to
// 4 pi; a constant colour c projects exactly to L_0 = 2 sqrt(pi) c. The window
// (for `bands` bands) scales band l by w_l.
EnvironmentSh project_environment(const Environment& env, ShWindow window = ShWindow::None, int bands = kShMaxBands);

// Rotates the coefficients (the environment turned by `rotation`).
EnvironmentSh rotate(const EnvironmentSh& sh, const glm::mat3& rotation);

// env_sh.json: {"format": "lightfarm.env_sh", "version": 1, "basis": …,
// "source", "bands", "window": {"kind", "factors"}, "coefficients": [[r,g,b] x16]}.
nlohmann::json to_json(const EnvironmentSh& sh);
EnvironmentSh environment_sh_from_json(const nlohmann::json& j);

// An environment spec as sh-shade takes it: env_sh.json, an image, or "R,G,B".
EnvironmentSh load_environment_sh(const std::string& spec, ShWindow window = ShWindow::None);

// A uniform sky: radiance 1 above the horizon (y > 0), 0 below: what "auto"
// band selection shades with when no environment is given.
Environment uniform_sky(int width = 128, int height = 64);

}  // namespace lf
