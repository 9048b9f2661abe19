// Shading with SH transfer, and what it is checked against: irradiance
// E = Σ T_i L_i (seed §2.4, its Listing 2.8 as a dot product), brute-force
// ray-traced irradiance, and the band count a scene needs.
#pragma once

#include "sh/environment.h"
#include "sh/sh_basis.h"
#include "scene/scene.h"
#include "trace/tracer.h"

#include <vector>

namespace lf {

// Irradiance (W/m²) from the first bands² coefficients.
glm::vec3 sh_irradiance(const ShCoefficients& transfer, const EnvironmentSh& env, int bands = kShMaxBands);

// Brute-force irradiance at every Scene vertex, shadowed like T^0:
// E = ∫ V L max(0, n·ω) dω by `samples` cosine-distributed rays per vertex,
// L from the environment's texels (nearest). Needs a current GL context.
std::vector<glm::vec3> reference_irradiance(const Scene& scene, const Tracer& tracer, const Environment& env,
                                            int samples, uint32_t seed = 7);

// Relative RMS difference of irradiance between `bands` and 4 bands over
// the given transfer vectors (RGB channel mean): sqrt(Σ (E_b - E_4)² / Σ E_4²).
double band_truncation_error(const std::vector<ShCoefficients>& transfer, const EnvironmentSh& env, int bands);

// "Model no more than a scene needs": the smallest band count whose
// band_truncation_error is <= target (4 if none is).
int choose_band_count(const std::vector<ShCoefficients>& transfer, const EnvironmentSh& env, double target);

}  // namespace lf
