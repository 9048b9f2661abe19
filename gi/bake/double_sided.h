// Which side of a double-sided surface its lightmap texels are baked for.
//
// A texel holds one value, for the side its normal faces. A double-sided
// surface renders from both sides, and exporters often leave its front facing
// away from where it is seen: the staircase's back rooms are walls whose
// fronts face the void outside the house, baked black, and black for every
// ray that lands on their lit inner side too. Each double-sided chart is
// therefore baked for the side the rest of the scene is on: the side from
// which more cosine rays hit geometry (the inside of a room rather than the
// void; the top of a ground plane with things on it rather than its
// underside). A chart with no clear answer keeps its front.
#pragma once

#include "scene/scene.h"
#include "trace/tracer.h"

#include <cstddef>
#include <cstdint>

namespace lf {

struct TurnedCharts {
    size_t charts = 0;     // double-sided charts turned round
    size_t triangles = 0;  // their triangles
    uint64_t rays = 0;     // traced to decide
};

// Turns every double-sided chart of `atlas_scene` (triangles connected by
// shared vertices: a generated atlas's charts, or the islands of a file's
// own UVs) whose back sees clearly more of the scene than its front: its
// triangles' winding and its vertices' normals are reversed, and
// Scene::triangle_turned records it (so that writers keep the file's own
// winding). `tracer` traces `atlas_scene`'s geometry (which turning does not
// change). Deterministic for a given scene.
TurnedCharts face_double_sided_charts_to_the_scene(Scene& atlas_scene, const Tracer& tracer);

}  // namespace lf
