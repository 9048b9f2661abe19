// Texels where the light changes (issue #35): a first look at each chart's
// direct light before the atlas is packed, so that charts where it changes
// within a texel (a shadow's edge, a lamp's pool) get more texels and
// charts it lights evenly fewer, at the same texel count in all
// (atlas.light_density; AtlasOptions::light_scales).
//
// From triplets of points on each chart (p, and p +- `texel` in a random
// direction along its triangle; one per 8 texels the chart would get, 8
// to 4,096), all lit by the same light samples (punctual lights exactly,
// emitter points, sky directions, each with its shadow ray), the chart's
// k = mean of (E(p) - (E(p + texel) + E(p - texel)) / 2)^2, E the
// irradiance's channel mean: the error of a lookup that interpolates
// between texels a texel either side of p. E is the direct light plus a
// first look at the indirect: each point's openness (the same cosine
// directions from the three points, a surface within 16 texels closing
// one in part) times the scene's mean direct irradiance times its mean
// albedo, what an open point gets over a closed one (light_density.cpp's
// chart_k), so a wall's foot or a contact keeps texels where the direct
// light alone is even. It is zero on a smooth
// gradient (first differences rewarded lamp pools and measured worse than
// uniform: docs/BENCHMARKS.md, "Texels where the light changes") and the
// light's jump at a shadow's edge. Across such an edge, that error
// covers the share of the chart within a texel of the edge, which is
// proportional to the texel's size h; the sum over charts of area x k x h /
// texel at a fixed texel count (sum of area / h^2) is least where the
// density 1/h goes as k^(1/3) (a Lagrange multiplier). So each chart's
// scale is k^(1/3), with a floor for the evenly lit ones (light changing by
// 1% of the scene's mean a texel apart), clamped to [kMinLightScale,
// kMaxLightScale], and normalized so that the sum of area x scale^2 over
// the charts scaled is their area: as many texels as without it.
#pragma once

#include "scene/scene.h"
#include "sh/environment.h"
#include "trace/tracer.h"

#include <cstddef>
#include <cstdint>
#include <vector>

namespace lf {

constexpr double kMinLightScale = 0.5;
constexpr double kMaxLightScale = 2.0;

struct LightScales {
    std::vector<double> scale;  // per chart id: its density over the scene's (1 where left as it is)
    std::vector<double> k;      // per chart id: mean squared difference of E a texel apart (0 where not measured)
    uint64_t rays = 0;          // traced to measure
};

// `chart[t]`: triangle t's chart id, below chart_count. Charts flagged in
// `leave` (unlit, glass: packed at their own scale) are not measured and
// keep 1. `texel`: the world size of a texel at the density the scene would
// get without this (the pairs' distance). `sky`: what escaping rays see
// (null: nothing).
LightScales light_driven_chart_scales(const Scene& scene, const Tracer& tracer, const std::vector<uint32_t>& chart,
                                      size_t chart_count, const std::vector<uint8_t>& leave, double texel,
                                      const Environment* sky);

}  // namespace lf
