// Charts that no light can reach, found from the geometry before the atlas
// is packed, so that they get few texels (AtlasOptions::find_unlit_charts).
//
// A closed interior's outer walls face the void: 40% of the staircase's atlas
// was black rectangles. Without a sky, light reaches a surface only from a
// punctual light or from another surface's front (or either side of a
// double-sided one). A chart is unlit when, from random points of it, no
// punctual light is visible and every cosine ray escapes the scene or lands
// on the back of a one-sided surface. The test is on the safe side: a chart
// that sees any surface counts as lit, even if that surface is dark itself.
#pragma once

#include "scene/scene.h"
#include "trace/tracer.h"

#include <cstddef>
#include <cstdint>
#include <vector>

namespace lf {

struct UnlitCharts {
    std::vector<uint8_t> unlit;  // per chart id: 1 where no light can reach it
    uint64_t rays = 0;           // traced to decide
};

// `chart[t]` is triangle t's chart id, below chart_count. With a sky, every
// chart is lit (a ray that escapes sees it).
UnlitCharts find_unlit_charts(const Scene& scene, const Tracer& tracer, const std::vector<uint32_t>& chart,
                              size_t chart_count, bool sky);

// Charts all of whose triangles are glass (Material::transmission > 0):
// light passes them (the tracer's see-through surfaces) and they reflect
// little of it, so by default they are packed like unlit charts, at
// kUnlitChartScale, unless the job asks for their texels (atlas.glass_texels).
// 1 per such chart id; `chart` as find_unlit_charts's.
std::vector<uint8_t> find_glass_charts(const Scene& scene, const std::vector<uint32_t>& chart, size_t chart_count);

}  // namespace lf
