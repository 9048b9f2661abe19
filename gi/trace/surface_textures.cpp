#include "trace/surface_textures.h"
#include "shaders/buffer_bindings.glsl"
#include "shaders/material_layout.glsl"

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

void put_vec3(uint32_t* at, glm::vec3 v) {
    for (int i = 0; i < 3; ++i) at[i] = glm::floatBitsToUint(v[i]);
}

// One material's record (material_layout.glsl).
void put_material(const Material& m, bool closed_volume, uint32_t base_texture, uint32_t emissive_texture,
                  uint32_t* record) {
    put_vec3(record + LF_MAT_BASE_COLOR, glm::vec3(m.base_color));
    put_vec3(record + LF_MAT_EMISSION, m.emission);
    record[LF_MAT_BASE_TEXTURE] = base_texture;
    record[LF_MAT_EMISSIVE_TEXTURE] = emissive_texture;
    record[LF_MAT_ALPHA] = glm::floatBitsToUint(m.base_color.a);
    record[LF_MAT_ALPHA_MODE] = m.alpha_mode == Material::AlphaMode::Mask    ? LF_ALPHA_MASK
                                : m.alpha_mode == Material::AlphaMode::Blend ? LF_ALPHA_BLEND
                                                                             : LF_ALPHA_OPAQUE;
    record[LF_MAT_ALPHA_CUTOFF] = glm::floatBitsToUint(m.alpha_cutoff);
    record[LF_MAT_TRANSMISSION] = glm::floatBitsToUint(m.transmission);
    put_vec3(record + LF_MAT_ATTENUATION, m.has_volume() ? m.attenuation : glm::vec3(0.0f));
    record[LF_MAT_OPEN_THICKNESS] = glm::floatBitsToUint(closed_volume ? 0.0f : m.thickness);
}

// MaterialTextures of surface_textures.glsl: materials, the texture table,
// then the texels. A texture without texels (not decoded) reads as white on
// the CPU, so its materials get no texture here; nor do those `which` leaves out.
std::vector<uint32_t> material_textures(const Scene& scene, SurfaceTextures::Which which, size_t& texture_bytes) {
    std::vector<uint32_t> out(LF_MATERIALS_FIRST + LF_MATERIAL_UINTS * scene.materials.size(), 0u);
    out[0] = uint32_t(scene.materials.size());
    std::vector<bool> used(scene.textures.size(), false);
    auto texture_ref = [&](int k, bool wanted) {
        if (!wanted || k < 0 || scene.textures[size_t(k)].texels.empty()) return 0u;
        used[size_t(k)] = true;
        return uint32_t(k) + 1u;
    };
    const bool all = which == SurfaceTextures::Which::All;
    const std::vector<bool> closed = scene.closed_volumes();
    for (size_t i = 0; i < scene.materials.size(); ++i) {
        const Material& m = scene.materials[i];
        put_material(m, closed[i], texture_ref(m.base_color_texture, all || m.is_see_through()),
                     texture_ref(m.emissive_texture, all), &out[LF_MATERIALS_FIRST + LF_MATERIAL_UINTS * i]);
    }
    out[1] = uint32_t(out.size());
    const size_t table = out.size();
    out.resize(table + 4 * scene.textures.size(), 0u);
    for (size_t k = 0; k < scene.textures.size(); ++k) {
        if (!used[k]) continue;
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

SurfaceTextures::SurfaceTextures(const Scene& scene, Which which) {
    const bool see_through = std::any_of(scene.materials.begin(), scene.materials.end(),
                                         [](const Material& m) { return m.is_see_through(); });
    // Only the tracer's see-through tests read them there: nothing to hold
    // for a scene whose surfaces are all opaque.
    const bool texcoords_needed = which == Which::All || see_through;
    std::vector<glm::vec4> texcoords(2 * std::max<size_t>(texcoords_needed ? scene.triangles.size() : 0, 1),
                                     glm::vec4(0.0f));
    for (size_t t = 0; texcoords_needed && t < scene.triangles.size(); ++t) {
        const glm::uvec3 tri = scene.triangles[t];
        texcoords[2 * t] = glm::vec4(scene.uv0[tri.x], scene.uv0[tri.y]);
        texcoords[2 * t + 1] = glm::vec4(scene.uv0[tri.z], uint_bits(scene.triangle_material[t]), 0.0f);
    }
    texcoords_ = GpuBuffer(texcoords);
    materials_ = GpuBuffer(material_textures(scene, which, texture_bytes_));
}

void SurfaceTextures::bind() const {
    texcoords_.bind(LF_BINDING_SURFACE_TEXCOORDS);
    materials_.bind(LF_BINDING_MATERIAL_TEXTURES);
}

}  // namespace lf
