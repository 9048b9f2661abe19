// Materials (base colour, emission, their textures) and KHR_lights_punctual.
#include "scene/gltf_build.h"
#include "scene/gltf_files.h"

#include <glm/gtc/constants.hpp>

#include <algorithm>
#include <cmath>
#include <map>

namespace lf::gltf {

namespace {

// glTF factors are in [0, 1]; exporters round, so a hair above 1 is accepted and clamped.
constexpr double kFactorSlack = 1e-3;

class MaterialBuilder {
public:
    MaterialBuilder(tinygltf::Model& model, const Errors& errors, ImageDecoder& images, const AccessorReader& reader,
                    Scene& scene, std::vector<std::string>* warnings)
        : model_(model), errors_(errors), images_(images), reader_(reader), scene_(scene), warnings_(warnings) {}

    Material convert(const tinygltf::Material& m, int index);

private:
    glm::vec3 factor(const std::vector<double>& values, size_t size, const std::string& where, const char* what,
                     bool clamp_to_one) const;
    // Scene texture for a material's texture reference, or -1.
    int texture(const tinygltf::TextureInfo& info, const std::string& where, const char* slot);
    // alphaMode and alphaCutoff, KHR_materials_transmission and
    // KHR_materials_volume's absorption: how light passes through.
    void read_see_through(const tinygltf::Material& m, const std::string& where, Material& out) const;
    // A number in an extension's object, or `fallback` when absent; fails
    // outside [lo, hi].
    double extension_number(const tinygltf::Value& ext, const char* key, double fallback, double lo, double hi,
                            const std::string& where) const;
    // Says per material what the bake does with a see-through surface.
    void describe_see_through(const Material& m, const std::string& where) const;

    tinygltf::Model& model_;
    const Errors& errors_;
    ImageDecoder& images_;
    const AccessorReader& reader_;
    Scene& scene_;
    std::vector<std::string>* warnings_;
    std::map<int, int> texture_of_image_;  // glTF image -> Scene::textures
};

glm::vec3 MaterialBuilder::factor(const std::vector<double>& values, size_t size, const std::string& where,
                                  const char* what, bool clamp_to_one) const {
    if (values.size() != size)
        errors_.fail(where + ": " + what + " has " + std::to_string(values.size()) + " values, not " +
                     std::to_string(size));
    glm::vec3 out(1.0f);
    for (size_t i = 0; i < size; ++i) {
        const double v = values[i];
        if (!std::isfinite(v) || v < 0.0 || (clamp_to_one && v > 1.0 + kFactorSlack))
            errors_.fail(where + ": " + what + " value " + std::to_string(v) + " is outside [0, 1]");
        if (i < 3) out[int(i)] = float(clamp_to_one ? std::min(v, 1.0) : v);
    }
    return out;
}

int MaterialBuilder::texture(const tinygltf::TextureInfo& info, const std::string& where, const char* slot) {
    if (info.index < 0) return -1;
    if (size_t(info.index) >= model_.textures.size()) {
        errors_.fail(where + ": " + slot + " texture " + std::to_string(info.index) + " does not exist (the file has " +
                     std::to_string(model_.textures.size()) + " textures)");
    }
    if (info.texCoord != 0)
        warnings_->push_back(where + ": " + slot + " texture uses TEXCOORD_" + std::to_string(info.texCoord) +
                             "; sampled with TEXCOORD_0");
    const int image = model_.textures[size_t(info.index)].source;
    if (image < 0) {
        // E.g. only an extension (KHR_texture_basisu, EXT_texture_webp) names the image.
        warnings_->push_back(where + ": " + slot + " texture " + std::to_string(info.index) +
                             " has no PNG/JPEG source; ignored");
        return -1;
    }
    if (size_t(image) >= model_.images.size()) {
        errors_.fail("texture", info.index,
                     "source image " + std::to_string(image) + " does not exist (the file has " +
                         std::to_string(model_.images.size()) + " images)");
    }
    if (const auto it = texture_of_image_.find(image); it != texture_of_image_.end()) return it->second;

    tinygltf::Image& img = model_.images[size_t(image)];
    // Checked from its header only (LoadLimits::decode_images): sizes, no pixels.
    const bool header_only = img.image.empty() && img.width > 0;
    if (img.bufferView >= 0 && img.image.empty() && !header_only) {
        // GLB-embedded: decoded here, from a view check_buffer_views() has checked.
        size_t size = 0;
        const unsigned char* bytes = reader_.view_data(img.bufferView, &size);
        images_.decode(&img, image, bytes, size);
    }
    if (img.image.empty() && img.width <= 0)
        errors_.fail(Errors::label("image", image, img.name),
                     "could not be loaded" + (img.uri.empty() ? std::string() : " from " + in_quotes(img.uri)));

    std::string name = img.name;
    if (name.empty()) name = img.uri.empty() || is_data_uri(img.uri) ? "image " + std::to_string(image) : img.uri;
    scene_.textures.push_back(srgb_texture(img, std::move(name)));
    // The float texture is what the Scene keeps; the RGBA8 copy is no longer needed.
    std::vector<unsigned char>().swap(img.image);
    const int slot_index = int(scene_.textures.size() - 1);
    texture_of_image_[image] = slot_index;
    return slot_index;
}

Material MaterialBuilder::convert(const tinygltf::Material& m, int index) {
    const std::string where = Errors::label("material", index, m.name);
    Material out;
    out.name = m.name.empty() ? "material " + std::to_string(index) : m.name;

    const std::vector<double>& base = m.pbrMetallicRoughness.baseColorFactor;
    const glm::vec3 rgb = factor(base, 4, where, "baseColorFactor", true);
    out.base_color = glm::vec4(rgb, float(std::min(base[3], 1.0)));
    out.base_color_texture = texture(m.pbrMetallicRoughness.baseColorTexture, where, "base colour");

    glm::vec3 emissive(0.0f);
    if (!m.emissiveFactor.empty()) emissive = factor(m.emissiveFactor, 3, where, "emissiveFactor", true);
    float strength = 1.0f;
    if (const auto it = m.extensions.find("KHR_materials_emissive_strength"); it != m.extensions.end()) {
        const tinygltf::Value& ext = it->second;
        if (ext.IsObject() && ext.Has("emissiveStrength")) {
            const tinygltf::Value& v = ext.Get("emissiveStrength");
            const double s = v.IsNumber() ? v.GetNumberAsDouble() : -1.0;
            if (!std::isfinite(s) || s < 0.0)
                errors_.fail(where + ": KHR_materials_emissive_strength emissiveStrength is not a non-negative number");
            strength = float(s);
        }
    }
    out.emission = emissive * strength;  // radiance in W/(sr·m²), DESIGN.md "Conventions"
    out.emissive_texture = texture(m.emissiveTexture, where, "emissive");
    out.double_sided = m.doubleSided;
    read_see_through(m, where, out);
    describe_see_through(out, where);
    return out;
}

double MaterialBuilder::extension_number(const tinygltf::Value& ext, const char* key, double fallback, double lo,
                                         double hi, const std::string& where) const {
    if (!ext.IsObject() || !ext.Has(key)) return fallback;
    const tinygltf::Value& v = ext.Get(key);
    const double x = v.IsNumber() ? v.GetNumberAsDouble() : std::nan("");
    if (!(x >= lo && x <= hi))
        errors_.fail(where + ": " + key + " is " + (v.IsNumber() ? std::to_string(x) : std::string("not a number")) +
                     ", outside [" + std::to_string(lo) + ", " + (std::isinf(hi) ? "inf" : std::to_string(hi)) + "]");
    return x;
}

void MaterialBuilder::read_see_through(const tinygltf::Material& m, const std::string& where, Material& out) const {
    if (m.alphaMode == "MASK") out.alpha_mode = Material::AlphaMode::Mask;
    else if (m.alphaMode == "BLEND") out.alpha_mode = Material::AlphaMode::Blend;
    else if (!m.alphaMode.empty() && m.alphaMode != "OPAQUE")
        errors_.fail(where + ": alphaMode " + in_quotes(m.alphaMode, 20) + " is not OPAQUE, MASK or BLEND");
    if (!std::isfinite(m.alphaCutoff) || m.alphaCutoff < 0.0)
        errors_.fail(where + ": alphaCutoff " + std::to_string(m.alphaCutoff) + " is not a non-negative number");
    out.alpha_cutoff = float(m.alphaCutoff);

    const auto transmission = m.extensions.find("KHR_materials_transmission");
    if (transmission == m.extensions.end()) return;
    const tinygltf::Value& ext = transmission->second;
    out.transmission = float(extension_number(ext, "transmissionFactor", 0.0, 0.0, 1.0 + kFactorSlack, where));
    out.transmission = std::min(out.transmission, 1.0f);
    if (ext.IsObject() && ext.Has("transmissionTexture"))
        warnings_->push_back(where + ": KHR_materials_transmission's transmissionTexture is ignored (its factor, " +
                             std::to_string(out.transmission) + ", holds over the whole surface)");
    // Absorption inside the volume (KHR_materials_volume): Beer-Lambert over
    // the path inside the mesh, attenuationColor being what is left after
    // attenuationDistance (Material::attenuation). A thin-walled surface
    // (thicknessFactor 0) absorbs nothing.
    const auto volume = m.extensions.find("KHR_materials_volume");
    if (volume == m.extensions.end()) return;
    const tinygltf::Value& vol = volume->second;
    const double thickness = extension_number(vol, "thicknessFactor", 0.0, 0.0, HUGE_VAL, where);
    const double distance = extension_number(vol, "attenuationDistance", HUGE_VAL, 1e-30, HUGE_VAL, where);
    glm::vec3 color(1.0f);
    if (vol.IsObject() && vol.Has("attenuationColor")) {
        const tinygltf::Value& c = vol.Get("attenuationColor");
        std::vector<double> values;
        for (size_t i = 0; c.IsArray() && i < c.ArrayLen(); ++i)
            values.push_back(c.Get(int(i)).IsNumber() ? c.Get(int(i)).GetNumberAsDouble() : -1.0);
        color = factor(values, 3, where, "KHR_materials_volume attenuationColor", true);
    }
    if (thickness > 0.0 && std::isfinite(distance)) {
        // A channel that keeps nothing (colour 0) absorbs at a finite rate
        // (-ln 1e-30 = 69 per distance), so that 0 x that rate stays 0.
        for (int c = 0; c < 3; ++c) out.attenuation[c] = float(-std::log(std::max(double(color[c]), 1e-30)) / distance);
        out.thickness = float(thickness);
    }
}

// What a bake does with a see-through material, said per material so that a
// user knows how the light will pass (issue #35).
void MaterialBuilder::describe_see_through(const Material& m, const std::string& where) const {
    if (m.alpha_mode == Material::AlphaMode::Mask)
        warnings_->push_back(where + ": alphaMode MASK (cut-out): light passes where base colour alpha < " +
                             std::to_string(m.alpha_cutoff) + ", and the rest casts shadows and bounces light");
    else if (m.alpha_mode == Material::AlphaMode::Blend)
        warnings_->push_back(where +
                             ": alphaMode BLEND: light passes in proportion to 1 - base colour alpha, untinted");
    if (m.transmission > 0.0f)
        warnings_->push_back(
            where + ": KHR_materials_transmission: " + std::to_string(m.transmission) +
            " of the light passes through, tinted by the base colour" +
            (m.has_volume() ? ", and KHR_materials_volume's absorption over the path inside the mesh" : "") +
            " (no refraction or reflection off the glass)");
}

const char* kLightTypes[] = {"point", "spot", "directional"};

}  // namespace

void add_materials(tinygltf::Model& model, const Errors& errors, ImageDecoder& images, const AccessorReader& reader,
                   Scene& scene, std::vector<std::string>* warnings) {
    MaterialBuilder builder(model, errors, images, reader, scene, warnings);
    scene.materials.reserve(model.materials.size() + 1);
    for (size_t i = 0; i < model.materials.size(); ++i)
        scene.materials.push_back(builder.convert(model.materials[i], int(i)));
}

void add_lights(const tinygltf::Model& model, const std::vector<PlacedNode>& lights, const Errors& errors, Scene& scene,
                std::vector<std::string>* warnings) {
    for (const PlacedNode& placed : lights) {
        const tinygltf::Light& l = model.lights[size_t(placed.item)];
        const std::string where = "light " + std::to_string(placed.item);
        PunctualLight out;
        out.name = l.name;
        if (l.type == kLightTypes[0]) out.type = PunctualLight::Type::Point;
        else if (l.type == kLightTypes[1]) out.type = PunctualLight::Type::Spot;
        else if (l.type == kLightTypes[2]) out.type = PunctualLight::Type::Directional;
        else errors.fail(where + ": type " + in_quotes(l.type, 20) + " is not point, spot or directional");

        glm::dvec3 color(1.0);
        if (!l.color.empty()) {
            if (l.color.size() != 3)
                errors.fail(where + ": color has " + std::to_string(l.color.size()) + " values, not 3");
            color = glm::dvec3(l.color[0], l.color[1], l.color[2]);
        }
        for (int c = 0; c < 3; ++c) {
            if (!std::isfinite(color[c]) || color[c] < 0.0)
                errors.fail(where + ": color is not finite and non-negative");
        }
        if (!std::isfinite(l.intensity) || l.intensity < 0.0)
            errors.fail(where + ": intensity is not finite and non-negative");
        if (!std::isfinite(l.range) || l.range < 0.0) errors.fail(where + ": range is not finite and positive");
        // Radiometric reading of glTF's photometric units (DESIGN.md "Conventions"): no 683 lm/W.
        out.intensity = glm::vec3(color * l.intensity);
        out.range = float(l.range);

        if (out.type == PunctualLight::Type::Spot) {
            const double inner = l.spot.innerConeAngle, outer = l.spot.outerConeAngle;
            if (!(inner >= 0.0 && inner < outer && outer <= glm::half_pi<double>() + 1e-6)) {
                errors.fail(where + ": spot cone angles inner " + std::to_string(inner) + ", outer " +
                            std::to_string(outer) + " are not 0 <= inner < outer <= pi/2");
            }
            out.inner_cone = float(inner);
            out.outer_cone = float(outer);
        }

        // A light shines down its node's local -Z.
        out.position = glm::vec3(placed.world * glm::dvec4(0.0, 0.0, 0.0, 1.0));
        const glm::dvec3 direction = glm::dmat3(placed.world) * glm::dvec3(0.0, 0.0, -1.0);
        const double length = glm::length(direction);
        if (!std::isfinite(out.position.x) || !std::isfinite(out.position.y) || !std::isfinite(out.position.z) ||
            !std::isfinite(length)) {
            errors.fail("node", placed.node,
                        "its transform takes light " + std::to_string(placed.item) + " to non-finite values");
        }
        if (length <= 0.0 && out.type != PunctualLight::Type::Point) {
            warnings->push_back("node " + std::to_string(placed.node) + ": transform collapses light " +
                                std::to_string(placed.item) + "'s direction; light skipped");
            continue;
        }
        if (length > 0.0) out.direction = glm::vec3(direction / length);
        scene.lights.push_back(out);
    }
}

}  // namespace lf::gltf
