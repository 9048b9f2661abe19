// The scene's materials and textures on the GPU (gi/shaders/surface_textures.glsl):
//  * every ray's: the tracer holds the materials and the base-colour
//    textures of the see-through surfaces (Which::SeeThrough), to let light
//    through cut-outs and glass (trace.glsl);
//  * for shaders that read albedo and emission at the exact point a ray lands
//    (LF_EXACT_TEXTURES): the path tracer that serves as the lightmap's
//    reference, and the probes' capture, bind every texture (Which::All)
//    after Tracer::bind(), at the same bindings: the same records, more
//    textures.
#pragma once

#include "gpu/shader.h"
#include "scene/scene.h"

#include <cstddef>

namespace lf {

class SurfaceTextures {
public:
    enum class Which { All, SeeThrough };
    explicit SurfaceTextures(const Scene& scene, Which which = Which::All);

    // Binds the two buffers at the bindings surface_textures.glsl declares.
    void bind() const;

    // Bytes the textures take on the GPU (half-float RGBA texels).
    size_t texture_bytes() const { return texture_bytes_; }

    // Textures wider or taller than this are halved (2x2 box) until they fit:
    // a bake's texels are centimetres, a 4096 texture's sub-millimetre, and
    // a studio's 16k textures would not fit in the GPU's memory.
    static constexpr int kMaxTextureSide = 4096;

private:
    GpuBuffer texcoords_, materials_;
    size_t texture_bytes_ = 0;
};

}  // namespace lf
