// Each output's method, by the output's name (protocol/outputs.h): the one
// table that ties an output to the code that bakes it. The job driver makes
// the methods from it; nothing else names a method.
#pragma once

#include "bake/prepared_scene.h"
#include "bake/progressive.h"
#include "bake_settings.h"

#include <memory>
#include <string>

namespace lf {

// Makes an output's method from the job's settings (the output's own, and
// the job's seed, environment and atlas). `prepared` outlives it.
using MethodFactory = std::unique_ptr<ProgressiveMethod> (*)(const PreparedScene& prepared,
                                                             const protocol::BakeSettings& settings);

// The factory of output `name`, or null for a name no method bakes.
MethodFactory method_factory(const std::string& name);

}  // namespace lf
