// What a ray needs where it lands, on the GPU, for every method that shades
// hits (the radiosity map, the probes): per triangle its lightmap UVs,
// sidedness, emission and emitter-sampling density, and albedo
// (lightmap_lookup.glsl's SurfaceTriangles); the emissive triangles chosen
// in proportion to their power (direct_light.glsl's Emitters); and the
// punctual lights (bindings in shaders/buffer_bindings.glsl); and where it
// escapes, the environment (EnvironmentLight).
#pragma once

#include "gpu/shader.h"
#include "scene/scene.h"
#include "trace/environment_light.h"

#include <glm/vec3.hpp>

#include <cstdint>

namespace lf {

class SceneShading {
public:
    // `environment`: what rays that escape see (null: black).
    explicit SceneShading(const Scene& scene, const Environment* environment = nullptr);

    // Binds the buffers at the bindings the shaders declare.
    void bind() const;
    // Sets a parameter block's LF_SHADING_PARAMS (shaders/params_block.glsl):
    // the counts direct_light.glsl samples, and the environment. Rays have
    // no length limit: they end at the scene's bounds.
    template <class Params>
    void fill(Params& p) const {
        p.emitter_count = emitter_count_;
        p.punctual_count = punctual_count_;
        p.far = 1e30f;
        environment_.fill(p);
    }

    uint32_t emitter_count() const { return emitter_count_; }
    uint32_t punctual_count() const { return punctual_count_; }

private:
    GpuBuffer surface_triangles_, emitters_, punctual_lights_;
    EnvironmentLight environment_;
    uint32_t emitter_count_ = 0, punctual_count_ = 0;
};

}  // namespace lf
