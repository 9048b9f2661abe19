#include "bake/surface_textures.h"
#include "shaders/buffer_bindings.glsl"

#include <glm/gtc/packing.hpp>

#include <algorithm>

namespace lf {

namespace {

// A texture halved by a 2x2 box filter (odd sides keep their last row or column).
Texture halved(const Texture& t) {
    Texture h;
    h.name = t.name;
    h.width = std::max(1, t.width / 2);
    h.height = std::max(1, t.height / 2);
    h.texels.resize(size_t(h.width) * size_t(h.height));
    for (int y = 0; y < h.height; ++y)
        for (int x = 0; x < h.width; ++x) {
            const int x0 = std::min(2 * x, t.width - 1), x1 = std::min(2 * x + 1, t.width - 1);
            const int y0 = std::min(2 * y, t.height - 1), y1 = std::min(2 * y + 1, t.height - 1);
            h.texels[size_t(y) * size_t(h.width) + size_t(x)] =
                0.25f * (t.fetch(x0, y0) + t.fetch(x1, y0) + t.fetch(x0, y1) + t.fetch(x1, y1));
        }
    return h;
}

void push_vec3(std::vector<uint32_t>& out, glm::vec3 v) {
    for (int i = 0; i < 3; ++i) out.push_back(uint32_t(glm::floatBitsToUint(v[i])));
}

// MaterialTextures of surface_textures.glsl: materials, the texture table,
// then the texels. A texture without texels (not decoded) reads as white on
// the CPU, so its materials get no texture here.
std::vector<uint32_t> material_textures(const Scene& scene, size_t& texture_bytes) {
    std::vector<uint32_t> out = {uint32_t(scene.materials.size()), 0u};
    auto texture_ref = [&](int k) {
        return k >= 0 && !scene.textures[size_t(k)].texels.empty() ? uint32_t(k) + 1u : 0u;
    };
    for (const Material& m : scene.materials) {
        push_vec3(out, glm::vec3(m.base_color));
        push_vec3(out, m.emission);
        out.push_back(texture_ref(m.base_color_texture));
        out.push_back(texture_ref(m.emissive_texture));
    }
    out[1] = uint32_t(out.size());
    const size_t table = out.size();
    out.resize(table + 4 * scene.textures.size(), 0u);
    for (size_t k = 0; k < scene.textures.size(); ++k) {
        if (scene.textures[k].texels.empty()) continue;
        Texture t = scene.textures[k];
        while (t.width > SurfaceTextures::kMaxTextureSide || t.height > SurfaceTextures::kMaxTextureSide) t = halved(t);
        out[table + 4 * k] = uint32_t(out.size());
        out[table + 4 * k + 1] = uint32_t(t.width);
        out[table + 4 * k + 2] = uint32_t(t.height);
        for (const glm::vec4& texel : t.texels) {
            out.push_back(glm::packHalf2x16(glm::vec2(texel.r, texel.g)));
            out.push_back(glm::packHalf2x16(glm::vec2(texel.b, texel.a)));
        }
        texture_bytes += 8 * t.texels.size();
    }
    return out;
}

}  // namespace

SurfaceTextures::SurfaceTextures(const Scene& scene) {
    std::vector<glm::vec4> texcoords(2 * std::max<size_t>(scene.triangles.size(), 1), glm::vec4(0.0f));
    for (size_t t = 0; t < scene.triangles.size(); ++t) {
        const glm::uvec3 tri = scene.triangles[t];
        texcoords[2 * t] = glm::vec4(scene.uv0[tri.x], scene.uv0[tri.y]);
        texcoords[2 * t + 1] = glm::vec4(scene.uv0[tri.z], uint_bits(scene.triangle_material[t]), 0.0f);
    }
    texcoords_ = GpuBuffer(texcoords);
    materials_ = GpuBuffer(material_textures(scene, texture_bytes_));
}

void SurfaceTextures::bind() const {
    texcoords_.bind(LF_BINDING_SURFACE_TEXCOORDS);
    materials_.bind(LF_BINDING_MATERIAL_TEXTURES);
}

}  // namespace lf
