#include "atlas/lightmapped_gltf.h"
#include "io/write_error.h"
#include "worker_protocol.h"
#include "scene/glb.h"
#include "scene/gltf_reread.h"

#include "util/parallel.h"
#include "display_tone.h"

#include <nlohmann/json.hpp>
#include <tiny_gltf.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <unistd.h>

namespace lf {
namespace {

[[noreturn]] void fail(const std::filesystem::path& file, const std::string& what) {
    throw std::runtime_error(file.filename().string() + ": " + what);
}

// Keeps each image's encoded bytes (PNG/JPEG as in the file) so they can be
// embedded unchanged; nothing is decoded.
bool keep_image_bytes(tinygltf::Image*, const int index, std::string*, std::string*, int, int,
                      const unsigned char* bytes, int size, void* user) {
    auto& images = *static_cast<std::vector<std::vector<unsigned char>>*>(user);
    if (index < 0) return false;
    if (images.size() <= size_t(index)) images.resize(size_t(index) + 1);
    images[size_t(index)].assign(bytes, bytes + std::max(size, 0));
    return true;
}

struct LoadedModel {
    tinygltf::Model model;
    std::vector<std::vector<unsigned char>> image_bytes;
};

size_t align_up(size_t n, size_t alignment) { return (n + alignment - 1) / alignment * alignment; }

// All buffers become buffer 0, which the GLB stores in its binary chunk.
void merge_buffers(tinygltf::Model& model) {
    if (model.buffers.empty()) model.buffers.emplace_back();
    std::vector<size_t> offset(model.buffers.size());
    std::vector<unsigned char> data;
    for (size_t b = 0; b < model.buffers.size(); ++b) {
        data.resize(align_up(data.size(), 16));
        offset[b] = data.size();
        data.insert(data.end(), model.buffers[b].data.begin(), model.buffers[b].data.end());
    }
    for (tinygltf::BufferView& view : model.bufferViews) {
        view.byteOffset += offset[size_t(view.buffer)];
        view.buffer = 0;
    }
    tinygltf::Buffer merged;
    merged.data = std::move(data);
    model.buffers = {std::move(merged)};
}

// Appends bytes as a new buffer view of buffer 0; returns its index.
int append_view(tinygltf::Model& model, const std::vector<unsigned char>& bytes, int target, size_t stride = 0) {
    auto& data = model.buffers[0].data;
    data.resize(align_up(data.size(), 16));
    tinygltf::BufferView view;
    view.buffer = 0;
    view.byteOffset = data.size();
    view.byteLength = bytes.size();
    view.byteStride = stride;
    view.target = target;
    data.insert(data.end(), bytes.begin(), bytes.end());
    model.bufferViews.push_back(view);
    return int(model.bufferViews.size() - 1);
}

std::string mime_type_of(const std::vector<unsigned char>& bytes, const std::string& declared) {
    if (!declared.empty()) return declared;
    if (bytes.size() >= 4 && bytes[0] == 0x89 && bytes[1] == 'P' && bytes[2] == 'N' && bytes[3] == 'G')
        return "image/png";
    return "image/jpeg";
}

// Images referenced by URI (files beside the .gltf, or data: URIs) are
// stored in the binary chunk, so the .glb stands alone.
void embed_images(LoadedModel& loaded) {
    tinygltf::Model& model = loaded.model;
    for (size_t i = 0; i < model.images.size(); ++i) {
        tinygltf::Image& image = model.images[i];
        if (image.bufferView >= 0 || i >= loaded.image_bytes.size() || loaded.image_bytes[i].empty()) continue;
        image.mimeType = mime_type_of(loaded.image_bytes[i], image.mimeType);
        image.bufferView = append_view(model, loaded.image_bytes[i], 0);
        image.uri.clear();
        image.image.clear();
    }
}

// An accessor's elements as tightly packed bytes, sparse substitution applied.
std::vector<unsigned char> accessor_bytes(const tinygltf::Model& model, const tinygltf::Accessor& accessor,
                                          size_t element_size) {
    std::vector<unsigned char> out(accessor.count * element_size, 0);
    if (accessor.bufferView >= 0) {
        const tinygltf::BufferView& view = model.bufferViews[size_t(accessor.bufferView)];
        const auto& data = model.buffers[size_t(view.buffer)].data;
        const size_t stride = view.byteStride ? view.byteStride : element_size;
        for (size_t i = 0; i < accessor.count; ++i) {
            const size_t at = view.byteOffset + accessor.byteOffset + i * stride;
            if (at + element_size > data.size()) throw std::runtime_error("accessor outside its buffer");
            std::memcpy(&out[i * element_size], &data[at], element_size);
        }
    }
    if (accessor.sparse.isSparse) {
        const auto& s = accessor.sparse;
        const tinygltf::BufferView& iv = model.bufferViews[size_t(s.indices.bufferView)];
        const tinygltf::BufferView& vv = model.bufferViews[size_t(s.values.bufferView)];
        const auto& idata = model.buffers[size_t(iv.buffer)].data;
        const auto& vdata = model.buffers[size_t(vv.buffer)].data;
        const size_t isize = size_t(tinygltf::GetComponentSizeInBytes(uint32_t(s.indices.componentType)));
        for (size_t k = 0; k < size_t(s.count); ++k) {
            const size_t ia = iv.byteOffset + size_t(s.indices.byteOffset) + k * isize;
            const size_t va = vv.byteOffset + size_t(s.values.byteOffset) + k * element_size;
            if (ia + isize > idata.size() || va + element_size > vdata.size())
                throw std::runtime_error("sparse accessor outside its buffer");
            uint32_t index = 0;
            if (isize == 1) index = idata[ia];
            else if (isize == 2) {
                uint16_t v;
                std::memcpy(&v, &idata[ia], 2);
                index = v;
            } else std::memcpy(&index, &idata[ia], 4);
            if (index >= accessor.count) throw std::runtime_error("sparse index out of range");
            std::memcpy(&out[size_t(index) * element_size], &vdata[va], element_size);
        }
    }
    return out;
}

// A new accessor holding the elements of `source_accessor` listed in
// `source_vertex`, in that order. Vertex attribute elements are kept 4-byte
// aligned as glTF requires.
int gather_accessor(tinygltf::Model& model, int source_accessor, const std::vector<uint32_t>& source_vertex,
                    bool is_position) {
    const tinygltf::Accessor src = model.accessors[size_t(source_accessor)];
    const size_t element_size = size_t(tinygltf::GetComponentSizeInBytes(uint32_t(src.componentType))) *
                                size_t(tinygltf::GetNumComponentsInType(uint32_t(src.type)));
    const std::vector<unsigned char> dense = accessor_bytes(model, src, element_size);
    const size_t stride = align_up(element_size, 4);
    std::vector<unsigned char> bytes(source_vertex.size() * stride, 0);
    for (size_t i = 0; i < source_vertex.size(); ++i)
        std::memcpy(&bytes[i * stride], &dense[size_t(source_vertex[i]) * element_size], element_size);

    tinygltf::Accessor out;
    out.name = src.name;
    out.componentType = src.componentType;
    out.type = src.type;
    out.normalized = src.normalized;
    out.count = source_vertex.size();
    out.bufferView = append_view(model, bytes, TINYGLTF_TARGET_ARRAY_BUFFER, stride == element_size ? 0 : stride);
    if (is_position && src.componentType == TINYGLTF_COMPONENT_TYPE_FLOAT && src.type == TINYGLTF_TYPE_VEC3) {
        // POSITION must carry exact bounds of what it holds.
        out.minValues.assign(3, 1e300);
        out.maxValues.assign(3, -1e300);
        for (size_t i = 0; i < source_vertex.size(); ++i) {
            float p[3];
            std::memcpy(p, &bytes[i * stride], sizeof p);
            for (int c = 0; c < 3; ++c) {
                out.minValues[size_t(c)] = std::min(out.minValues[size_t(c)], double(p[c]));
                out.maxValues[size_t(c)] = std::max(out.maxValues[size_t(c)], double(p[c]));
            }
        }
    }
    model.accessors.push_back(out);
    return int(model.accessors.size() - 1);
}

// The lightmap page a triangle's charts lie on (its UV1's centre's: a chart
// never crosses a page).
int triangle_page(const Scene& scene, size_t t) {
    const glm::uvec3& tri = scene.triangles[t];
    return scene.lightmap_pages.page_of((scene.uv1[tri.x].y + scene.uv1[tri.y].y + scene.uv1[tri.z].y) / 3.0f);
}

int add_float_accessor(tinygltf::Model& model, const VertexAttribute& attribute, uint32_t vertex_count) {
    static const int types[] = {0, TINYGLTF_TYPE_SCALAR, TINYGLTF_TYPE_VEC2, TINYGLTF_TYPE_VEC3, TINYGLTF_TYPE_VEC4};
    if (attribute.components < 1 || attribute.components > 4 ||
        attribute.values.size() != size_t(vertex_count) * size_t(attribute.components))
        throw std::runtime_error("attribute " + attribute.name + ": " + std::to_string(attribute.values.size()) +
                                 " values for " + std::to_string(vertex_count) + " vertices of " +
                                 std::to_string(attribute.components) + " components");
    std::vector<unsigned char> bytes(attribute.values.size() * sizeof(float));
    std::memcpy(bytes.data(), attribute.values.data(), bytes.size());
    tinygltf::Accessor accessor;
    accessor.componentType = TINYGLTF_COMPONENT_TYPE_FLOAT;
    accessor.type = types[attribute.components];
    accessor.count = vertex_count;
    accessor.bufferView = append_view(model, bytes, TINYGLTF_TARGET_ARRAY_BUFFER);
    model.accessors.push_back(accessor);
    return int(model.accessors.size() - 1);
}

// The instance's triangles as glTF indices local to the primitive, in the
// file's own winding: the loader turned mirrored nodes' triangles around to
// make them counter-clockwise in world space, and the bake may have turned
// double-sided ones to face the scene; turning them back restores it.
// With `page` >= 0, only the triangles on that lightmap page (triangle_page).
int add_index_accessor(tinygltf::Model& model, const Scene& scene, const PrimitiveInstance& inst, int page = -1) {
    std::vector<unsigned char> bytes;
    bytes.reserve(size_t(inst.triangle_count) * 3 * sizeof(uint32_t));
    for (uint32_t i = 0; i < inst.triangle_count; ++i) {
        const size_t t = inst.first_triangle + i;
        if (page >= 0 && triangle_page(scene, t) != page) continue;
        glm::uvec3 tri = scene.triangles[t] - glm::uvec3(inst.first_vertex);
        const bool turned = !scene.triangle_turned.empty() && scene.triangle_turned[t];
        if (inst.mirrored != turned) std::swap(tri.y, tri.z);
        const auto* b = reinterpret_cast<const unsigned char*>(&tri);
        bytes.insert(bytes.end(), b, b + 12);
    }
    tinygltf::Accessor accessor;
    accessor.componentType = TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT;
    accessor.type = TINYGLTF_TYPE_SCALAR;
    accessor.count = bytes.size() / sizeof(uint32_t);
    accessor.bufferView = append_view(model, bytes, TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER);
    model.accessors.push_back(accessor);
    return int(model.accessors.size() - 1);
}

// The glTF vertex of each of the instance's vertices.
std::vector<uint32_t> instance_sources(const Scene& scene, const PrimitiveInstance& inst) {
    std::vector<uint32_t> sources(inst.vertex_count);
    for (uint32_t k = 0; k < inst.vertex_count; ++k)
        sources[k] = scene.source_vertex.empty() ? k : scene.source_vertex[inst.first_vertex + k];
    return sources;
}

// glTF numbers an indexed semantic without gaps (the validator's
// MESH_PRIMITIVE_INDEXED_SEMANTIC_CONTINUITY): TEXCOORD_1, the lightmap's
// UVs, only beside a TEXCOORD_0. A primitive that had none gets the next
// set's accessor as its TEXCOORD_0 as well (one accessor, two names): no
// material of the file read TEXCOORD_0, since it had none.
void fill_texcoord_gaps(tinygltf::Primitive& primitive) {
    int highest = -1;
    for (const auto& [name, accessor] : primitive.attributes)
        if (name.rfind("TEXCOORD_", 0) == 0) highest = std::max(highest, std::atoi(name.c_str() + 9));
    for (int n = highest - 1; n >= 0; --n) {
        const std::string name = "TEXCOORD_" + std::to_string(n);
        if (!primitive.attributes.count(name))
            primitive.attributes[name] = primitive.attributes.at("TEXCOORD_" + std::to_string(n + 1));
    }
}

void add_vertex_attributes(tinygltf::Model& model, tinygltf::Primitive& primitive, const Scene& scene,
                           const PrimitiveInstance& inst, const std::vector<VertexAttribute>& attributes,
                           const std::filesystem::path& source) {
    auto position = primitive.attributes.find("POSITION");
    if (position == primitive.attributes.end()) fail(source, "mesh " + std::to_string(inst.mesh) + " has no POSITION");
    const size_t gltf_count = model.accessors[size_t(position->second)].count;
    const std::vector<uint32_t> sources = instance_sources(scene, inst);
    for (uint32_t s : sources)
        if (s >= gltf_count) fail(source, "scene does not match the file (mesh " + std::to_string(inst.mesh) + ")");
    auto added = [&](const std::string& name) {
        for (const VertexAttribute& a : attributes)
            if (a.name == name) return true;
        return false;
    };

    bool identity = sources.size() == gltf_count;
    for (uint32_t k = 0; identity && k < sources.size(); ++k) identity = sources[k] == k;
    if (!identity) {
        // Split vertices: every per-vertex array is gathered anew, and the
        // triangles are written against the new vertices.
        for (auto& [name, accessor] : primitive.attributes)
            if (!added(name)) accessor = gather_accessor(model, accessor, sources, name == "POSITION");
        for (auto& target : primitive.targets)
            for (auto& [name, accessor] : target) accessor = gather_accessor(model, accessor, sources, false);
        primitive.indices = add_index_accessor(model, scene, inst);
        primitive.mode = TINYGLTF_MODE_TRIANGLES;
    }
    for (const VertexAttribute& a : attributes) {
        try {
            primitive.attributes[a.name] = add_float_accessor(model, a, inst.vertex_count);
        } catch (const std::runtime_error& e) {
            fail(source, "mesh " + std::to_string(inst.mesh) + " primitive " + std::to_string(inst.primitive) + ": " +
                             e.what());
        }
    }
    fill_texcoord_gaps(primitive);
}

// tinygltf writes a perspective camera's "zfar" even when it is 0 (its
// "infinite projection"), which the glTF schema forbids (zfar > 0 or absent):
// the GLB's JSON chunk is rewritten without it. `glb` is a whole GLB file.
void drop_zero_zfar(std::string& glb, const std::filesystem::path& out) {
    if (glb.size() < 20 || glb::read_u32(glb.data(), 16) != glb::kChunkJson) fail(out, "tinygltf wrote no JSON chunk");
    const uint32_t json_length = glb::read_u32(glb.data(), 12);
    nlohmann::json doc = nlohmann::json::parse(glb.substr(20, json_length));
    bool changed = false;
    if (doc.contains("cameras"))
        for (auto& camera : doc["cameras"])
            if (camera.contains("perspective") && camera["perspective"].value("zfar", 1.0) == 0.0) {
                camera["perspective"].erase("zfar");
                changed = true;
            }
    if (!changed) return;
    std::string json = doc.dump();
    json.resize((json.size() + 3) / 4 * 4, ' ');  // chunks are 4-byte aligned, JSON padded with spaces
    const std::string rest = glb.substr(20 + json_length);
    std::string rebuilt = glb.substr(0, 20) + json + rest;
    glb::write_u32(rebuilt.data(), 8, uint32_t(rebuilt.size()));
    glb::write_u32(rebuilt.data(), 12, uint32_t(json.size()));
    glb = std::move(rebuilt);
}

void write_atomically(tinygltf::Model& model, const std::filesystem::path& out) {
    const std::filesystem::path temp =
        out.parent_path() / protocol::temporary_file_name(out.filename().string(), long(::getpid()));
    {
        std::ostringstream encoded;
        tinygltf::TinyGLTF gltf;
        bool ok = gltf.WriteGltfSceneToStream(&model, encoded, false, true);
        std::string glb = encoded.str();
        if (ok) drop_zero_zfar(glb, out);
        if (!ok) fail(out, "tinygltf could not encode the model");
        std::ofstream stream(temp, std::ios::binary | std::ios::trunc);
        if (!stream) throw write_error(temp);
        stream.write(glb.data(), std::streamsize(glb.size()));
        stream.close();  // the last bytes reach the file (and a full disk shows) here
        if (!stream) {
            const WriteError error = write_error(temp);
            std::error_code ignored;
            std::filesystem::remove(temp, ignored);
            throw error;
        }
    }
    commit_file(temp, out);
}

void use_extension(tinygltf::Model& model, const std::string& name) {
    if (std::find(model.extensionsUsed.begin(), model.extensionsUsed.end(), name) == model.extensionsUsed.end())
        model.extensionsUsed.push_back(name);
}

// A new material for primitives that had none: glTF's default material is
// metallic (metallicFactor 1), the scene loader's is white Lambertian.
int add_default_lambertian_material(tinygltf::Model& model) {
    tinygltf::Material m;
    m.name = "lightfarm default (white Lambertian)";
    m.pbrMetallicRoughness.metallicFactor = 0.0;
    m.pbrMetallicRoughness.roughnessFactor = 1.0;
    model.materials.push_back(m);
    return int(model.materials.size() - 1);
}

// A PNG's strips compressed on every core (protocol/png.h).
void png_strips_in_parallel(size_t strips, const std::function<void(size_t)>& strip) { parallel_for(strips, 1, strip); }

// An embedded PNG texture (linear filtering, clamped: baked maps are linear,
// not sRGB, and end at their charts); returns its texture index.
int add_png_texture(tinygltf::Model& model, const std::string& png, const std::string& name) {
    tinygltf::Image image;
    image.name = name;
    image.mimeType = "image/png";
    image.bufferView = append_view(model, std::vector<unsigned char>(png.begin(), png.end()), 0);
    model.images.push_back(image);
    tinygltf::Sampler sampler;
    sampler.magFilter = TINYGLTF_TEXTURE_FILTER_LINEAR;
    sampler.minFilter = TINYGLTF_TEXTURE_FILTER_LINEAR;
    sampler.wrapS = sampler.wrapT = TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE;
    model.samplers.push_back(sampler);
    tinygltf::Texture texture;
    texture.source = int(model.images.size() - 1);
    texture.sampler = int(model.samplers.size() - 1);
    model.textures.push_back(texture);
    return int(model.textures.size() - 1);
}

// A baked primitive, and the lightmap page its triangles lie on
// (kNoLightmap: its mesh has none, PrimitiveInstance::has_lightmap).
constexpr int kNoLightmap = -1;
struct BakedPrimitive {
    tinygltf::Primitive* primitive;
    int page = 0;
};

// The materials of each page's primitives, a default one given to those
// without. A material used on several pages is copied for each page after
// its first, as each page's materials take that page's maps; one used also
// by a primitive without a lightmap, likewise, which keeps it as it was.
std::vector<std::set<int>> materials_by_page(tinygltf::Model& model, const std::vector<BakedPrimitive>& baked,
                                             int pages) {
    int default_material = -1;
    std::map<int, int> first_page;              // material -> the page that keeps it
    std::map<std::pair<int, int>, int> copies;  // (material, page) -> its copy
    std::vector<std::set<int>> materials(size_t(std::max(pages, 1)));
    for (const BakedPrimitive& b : baked) {
        int& material = b.primitive->material;
        if (material < 0) {
            if (default_material < 0) default_material = add_default_lambertian_material(model);
            material = default_material;
        }
        const int page = first_page.try_emplace(material, b.page).first->second;
        if (page != b.page) {
            auto [copy, added] = copies.try_emplace({material, b.page}, int(model.materials.size()));
            if (added) {
                tinygltf::Material m = model.materials[size_t(material)];
                m.name += b.page == kNoLightmap ? " (no lightmap)"
                          : pages == 1          ? " (lightmapped)"
                                                : " (lightmap page " + std::to_string(b.page) + ")";
                model.materials.push_back(std::move(m));
            }
            material = copy->second;
        }
        if (b.page != kNoLightmap) materials[size_t(b.page)].insert(material);
    }
    return materials;
}

// Page `page`'s rows of an image of the stacked pages (channels bytes per texel).
std::vector<uint8_t> page_rows(const std::vector<uint8_t>& pixels, int width, int channels, const LightmapPages& pages,
                               int page) {
    if (pages.count == 1) return pixels;
    const size_t row = size_t(width) * size_t(channels);
    const auto first = pixels.begin() + std::ptrdiff_t(size_t(page) * size_t(pages.stride()) * row);
    return {first, first + std::ptrdiff_t(size_t(pages.rows) * row)};
}

int page_height(const LightmapPages& pages, int height) { return pages.count == 1 ? height : pages.rows; }

// The lightmap applied with MOZ_lightmap to each page's materials.
void embed_lightmap(tinygltf::Model& model, const std::vector<std::set<int>>& materials, const LightmapPages& pages,
                    const protocol::RgbmImage& lightmap) {
    tinygltf::Value::Object extras{{"encoding", tinygltf::Value(std::string("RGBM"))},
                                   {"rgbm_range", tinygltf::Value(double(lightmap.range))}};
    for (int page = 0; page < pages.count; ++page) {
        const protocol::RgbmImage image{lightmap.width, page_height(pages, lightmap.height), lightmap.range,
                                        page_rows(lightmap.rgba, lightmap.width, 4, pages, page)};
        const std::string name = pages.count == 1 ? "" : " page " + std::to_string(page);
        const int texture =
            add_png_texture(model, protocol::rgbm_png(image, png_strips_in_parallel), "lightmap (RGBM)" + name);
        tinygltf::Value::Object extension{{"index", tinygltf::Value(texture)},
                                          {"texCoord", tinygltf::Value(1)},
                                          {"intensity", tinygltf::Value(M_PI)},
                                          {"extras", tinygltf::Value(extras)}};
        for (int m : materials[size_t(page)])
            model.materials[size_t(m)].extensions["MOZ_lightmap"] = tinygltf::Value(extension);
    }
    use_extension(model, "MOZ_lightmap");
}

// Ambient occlusion as the core occlusionTexture of each page's materials.
void embed_occlusion(tinygltf::Model& model, const std::vector<std::set<int>>& materials, const LightmapPages& pages,
                     const GreyImage& occlusion) {
    for (int page = 0; page < pages.count; ++page) {
        const std::vector<uint8_t> grey = page_rows(occlusion.values, occlusion.width, 1, pages, page);
        std::vector<uint8_t> rgb(grey.size() * 3);
        for (size_t i = 0; i < grey.size(); ++i) rgb[3 * i] = rgb[3 * i + 1] = rgb[3 * i + 2] = grey[i];
        const std::string png = protocol::encode_png(rgb.data(), occlusion.width, page_height(pages, occlusion.height),
                                                     3, png_strips_in_parallel);
        const int texture = add_png_texture(
            model, png, "ambient occlusion" + (pages.count == 1 ? "" : " page " + std::to_string(page)));
        for (int m : materials[size_t(page)]) {
            tinygltf::OcclusionTextureInfo& info = model.materials[size_t(m)].occlusionTexture;
            info = tinygltf::OcclusionTextureInfo();
            info.index = texture;
            info.texCoord = 1;
            info.strength = 1.0;
        }
    }
}

// The baked look as every material's only texture, unlit (write_unlit_glb).
void embed_unlit_look(tinygltf::Model& model, const std::vector<std::set<int>>& materials, const LightmapPages& pages,
                      const ColourImage& look) {
    std::set<std::string> dropped;
    for (int page = 0; page < pages.count; ++page) {
        const std::vector<uint8_t> rgb = page_rows(look.rgb, look.width, 3, pages, page);
        const std::string png =
            protocol::encode_png(rgb.data(), look.width, page_height(pages, look.height), 3, png_strips_in_parallel);
        const int texture = add_png_texture(
            model, png, "baked look (sRGB)" + (pages.count == 1 ? "" : " page " + std::to_string(page)));
        for (int m : materials[size_t(page)]) {
            tinygltf::Material& material = model.materials[size_t(m)];
            const double alpha = material.pbrMetallicRoughness.baseColorFactor.at(3);
            material.pbrMetallicRoughness = tinygltf::PbrMetallicRoughness();
            material.pbrMetallicRoughness.baseColorFactor = {1.0, 1.0, 1.0, alpha};
            material.pbrMetallicRoughness.baseColorTexture.index = texture;
            material.pbrMetallicRoughness.baseColorTexture.texCoord = 1;
            material.normalTexture = tinygltf::NormalTextureInfo();
            material.occlusionTexture = tinygltf::OcclusionTextureInfo();
            material.emissiveTexture = tinygltf::TextureInfo();
            material.emissiveFactor = {0.0, 0.0, 0.0};
            for (const auto& [name, value] : material.extensions) dropped.insert(name);
            material.extensions.clear();  // transmission, emissive strength …: the look holds their effect
            material.extensions["KHR_materials_unlit"] = tinygltf::Value(tinygltf::Value::Object());
        }
    }
    // An extension no material uses any more is no longer used, or required.
    for (const tinygltf::Material& material : model.materials)
        for (const auto& [name, value] : material.extensions) dropped.erase(name);
    for (std::vector<std::string>* list : {&model.extensionsUsed, &model.extensionsRequired})
        std::erase_if(*list, [&](const std::string& name) { return dropped.count(name) > 0; });
    use_extension(model, "KHR_materials_unlit");
}

// Each node placement of a mesh gets its own mesh (each has its own atlas
// region): the first node keeps the original, every further node a copy.
// Returns the mesh written for each node.
std::map<int, int> mesh_per_node(tinygltf::Model& model, const Scene& scene, const std::filesystem::path& source_gltf) {
    std::map<int, int> mesh_of_node;  // node -> mesh index written for it
    std::vector<bool> mesh_taken(model.meshes.size(), false);
    for (const PrimitiveInstance& inst : scene.instances) {
        if (auto seen = mesh_of_node.find(inst.node); seen != mesh_of_node.end()) {
            if (model.nodes[size_t(inst.node)].mesh != seen->second) fail(source_gltf, "scene does not match the file");
            continue;
        }
        if (inst.node < 0 || size_t(inst.node) >= model.nodes.size() || inst.mesh < 0 ||
            size_t(inst.mesh) >= mesh_taken.size() || model.nodes[size_t(inst.node)].mesh != inst.mesh)
            fail(source_gltf, "scene does not match the file (node " + std::to_string(inst.node) + ")");
        int mesh = inst.mesh;
        if (mesh_taken[size_t(mesh)]) {
            model.meshes.push_back(model.meshes[size_t(mesh)]);
            mesh = int(model.meshes.size() - 1);
            model.nodes[size_t(inst.node)].mesh = mesh;
        }
        mesh_taken[size_t(inst.mesh)] = true;
        mesh_of_node[inst.node] = mesh;
    }
    return mesh_of_node;
}

// A primitive whose triangles lie on several lightmap pages becomes one
// primitive per page (the same vertices, each page's triangles), and each
// says in its extras its page (lightfarm_lightmap_page) and where that page
// lies in the files that hold every page stacked, lightmap.exr
// (lightfarm_lightmap_stacked_v: [offset, scale], v there = offset + scale
// x TEXCOORD_1's v); with one page, nothing changes. Returns the (mesh,
// primitive index, page) of each piece; a primitive without a lightmap
// stays whole, on kNoLightmap, and says so in its extras
// (lightfarm_no_lightmap: a file's own TEXCOORD_1 may still be there).
struct PrimitivePiece {
    int mesh, primitive, page;
    uint32_t triangles;
};

std::vector<PrimitivePiece> split_by_page(tinygltf::Model& model, const Scene& scene, const PrimitiveInstance& inst,
                                          int mesh) {
    std::vector<PrimitivePiece> pieces;
    if (!inst.has_lightmap()) {
        tinygltf::Primitive& primitive = model.meshes[size_t(mesh)].primitives[size_t(inst.primitive)];
        tinygltf::Value::Object extras =
            primitive.extras.IsObject() ? primitive.extras.Get<tinygltf::Value::Object>() : tinygltf::Value::Object();
        extras["lightfarm_no_lightmap"] = tinygltf::Value(true);
        primitive.extras = tinygltf::Value(extras);
        return {{mesh, inst.primitive, kNoLightmap, inst.triangle_count}};
    }
    if (scene.lightmap_pages.count == 1) return {{mesh, inst.primitive, 0, inst.triangle_count}};
    std::map<int, uint32_t> pages;  // page -> its triangles
    for (uint32_t i = 0; i < inst.triangle_count; ++i) ++pages[triangle_page(scene, inst.first_triangle + i)];
    auto& primitives = model.meshes[size_t(mesh)].primitives;
    for (const auto& [page, triangles] : pages) {
        int index = inst.primitive;
        if (page != pages.begin()->first) {
            primitives.push_back(primitives[size_t(inst.primitive)]);
            index = int(primitives.size() - 1);
        }
        tinygltf::Primitive& piece = primitives[size_t(index)];
        if (pages.size() > 1) {
            piece.indices = add_index_accessor(model, scene, inst, page);
            piece.mode = TINYGLTF_MODE_TRIANGLES;
        }
        tinygltf::Value::Object extras =
            piece.extras.IsObject() ? piece.extras.Get<tinygltf::Value::Object>() : tinygltf::Value::Object();
        const LightmapPages& layout = scene.lightmap_pages;
        extras["lightfarm_lightmap_page"] = tinygltf::Value(page);
        extras["lightfarm_lightmap_stacked_v"] = tinygltf::Value(
            tinygltf::Value::Array{tinygltf::Value(double(page) * layout.stride() / layout.total_rows()),
                                   tinygltf::Value(double(layout.rows) / layout.total_rows())});
        piece.extras = tinygltf::Value(extras);
        pieces.push_back({mesh, index, page, triangles});
    }
    return pieces;
}

// Each mesh also says, in its own extras, the page of each of its
// primitives in order (lightfarm_lightmap_pages, -1 without a lightmap) and
// their triangles (lightfarm_primitive_triangles): importers that drop
// primitives' extras keep a mesh's (Blender's, which joins a mesh's
// primitives into one mesh in their order: the add-on in blender/ finds
// each triangle's page so).
void describe_pieces_per_mesh(tinygltf::Model& model, const std::vector<PrimitivePiece>& pieces) {
    std::map<int, std::map<int, const PrimitivePiece*>> by_mesh;
    for (const PrimitivePiece& piece : pieces) by_mesh[piece.mesh][piece.primitive] = &piece;
    for (const auto& [mesh, primitives] : by_mesh) {
        tinygltf::Mesh& m = model.meshes[size_t(mesh)];
        if (primitives.size() != m.primitives.size()) continue;  // not every primitive baked: say nothing
        tinygltf::Value::Array pages, triangles;
        for (const auto& [index, piece] : primitives) {
            pages.push_back(tinygltf::Value(piece->page));  // kNoLightmap: -1
            triangles.push_back(tinygltf::Value(int(piece->triangles)));
        }
        tinygltf::Value::Object extras =
            m.extras.IsObject() ? m.extras.Get<tinygltf::Value::Object>() : tinygltf::Value::Object();
        extras["lightfarm_lightmap_pages"] = tinygltf::Value(pages);
        extras["lightfarm_primitive_triangles"] = tinygltf::Value(triangles);
        m.extras = tinygltf::Value(extras);
    }
}

// write_glb_with_vertex_attributes, and the lightmap embedded when given.
// A light counts once (DESIGN.md "Outputs"): where the glb's lightmap holds
// the punctual lights' direct light, an engine or viewer that lit the
// lightmapped materials with them again would count it twice (a sun through
// a window came out twice as bright, monkey.glb 23%). So they leave the
// file, nodes' references and the extension's declarations with them, and
// the asset's extras name them, "lightfarm_baked_lights": [{"name", "type",
// "node"}], for an engine that wants to know what the lightmap holds.
void drop_baked_lights(tinygltf::Model& model) {
    if (model.lights.empty()) return;
    tinygltf::Value::Array baked;
    for (size_t n = 0; n < model.nodes.size(); ++n) {
        tinygltf::Node& node = model.nodes[n];
        const auto it = node.extensions.find("KHR_lights_punctual");
        if (it == node.extensions.end()) continue;
        const tinygltf::Value& index = it->second.Get("light");
        if (index.IsInt() && index.Get<int>() >= 0 && size_t(index.Get<int>()) < model.lights.size()) {
            const tinygltf::Light& light = model.lights[size_t(index.Get<int>())];
            tinygltf::Value::Object entry;
            entry["name"] = tinygltf::Value(light.name);
            entry["type"] = tinygltf::Value(light.type);
            entry["node"] = tinygltf::Value(int(n));
            baked.emplace_back(entry);
        }
        node.extensions.erase(it);
    }
    model.lights.clear();
    model.extensions.erase("KHR_lights_punctual");
    for (std::vector<std::string>* list : {&model.extensionsUsed, &model.extensionsRequired})
        list->erase(std::remove(list->begin(), list->end(), "KHR_lights_punctual"), list->end());
    tinygltf::Value::Object extras;
    if (model.asset.extras.IsObject())
        for (const std::string& key : model.asset.extras.Keys()) extras[key] = model.asset.extras.Get(key);
    extras["lightfarm_baked_lights"] = tinygltf::Value(baked);
    model.asset.extras = tinygltf::Value(extras);
}

void write_glb(const std::filesystem::path& source_gltf, const Scene& scene,
               const std::vector<std::vector<VertexAttribute>>& per_instance, const std::filesystem::path& out_glb,
               bool unlit_materials, const LitSceneMaps& maps, bool lights_baked, const ColourImage* look = nullptr) {
    if (per_instance.size() != scene.instances.size())
        fail(source_gltf, "attributes for " + std::to_string(per_instance.size()) + " primitives, the scene has " +
                              std::to_string(scene.instances.size()));
    LoadedModel loaded;
    loaded.model = reread_gltf(source_gltf, &keep_image_bytes, &loaded.image_bytes);
    tinygltf::Model& model = loaded.model;
    merge_buffers(model);
    embed_images(loaded);
    if (lights_baked) drop_baked_lights(model);

    std::map<int, int> mesh_of_node = mesh_per_node(model, scene, source_gltf);
    std::vector<PrimitivePiece> pieces;  // every baked primitive, on its page
    for (size_t i = 0; i < scene.instances.size(); ++i) {
        const PrimitiveInstance& inst = scene.instances[i];
        const int mesh = mesh_of_node[inst.node];
        auto& primitives = model.meshes[size_t(mesh)].primitives;
        if (inst.primitive < 0 || size_t(inst.primitive) >= primitives.size())
            fail(source_gltf, "scene does not match the file (mesh " + std::to_string(inst.mesh) + ")");
        add_vertex_attributes(model, primitives[size_t(inst.primitive)], scene, inst, per_instance[i], source_gltf);
        for (const auto& piece : split_by_page(model, scene, inst, mesh)) pieces.push_back(piece);
    }
    describe_pieces_per_mesh(model, pieces);
    // Pointers once every piece is in place (a split appends primitives).
    std::vector<BakedPrimitive> baked;
    for (const PrimitivePiece& piece : pieces)
        baked.push_back({&model.meshes[size_t(piece.mesh)].primitives[size_t(piece.primitive)], piece.page});
    if (unlit_materials && !model.materials.empty()) {
        for (tinygltf::Material& m : model.materials)
            m.extensions["KHR_materials_unlit"] = tinygltf::Value(tinygltf::Value::Object());
        use_extension(model, "KHR_materials_unlit");
    }
    if (maps.lightmap || maps.occlusion || look) {
        const LightmapPages& pages = scene.lightmap_pages;
        const std::vector<std::set<int>> materials = materials_by_page(model, baked, pages.count);
        if (maps.lightmap) embed_lightmap(model, materials, pages, *maps.lightmap);
        if (maps.occlusion) embed_occlusion(model, materials, pages, *maps.occlusion);
        if (look) embed_unlit_look(model, materials, pages, *look);
    }
    write_atomically(model, out_glb);
}

// TEXCOORD_1 = the scene's lightmap UVs, per instance, each on its page;
// none for an instance without a lightmap.
std::vector<std::vector<VertexAttribute>> lightmap_uvs(const Scene& scene) {
    std::vector<std::vector<VertexAttribute>> uv1(scene.instances.size());
    for (size_t i = 0; i < scene.instances.size(); ++i) {
        const PrimitiveInstance& inst = scene.instances[i];
        if (!inst.has_lightmap()) continue;
        // A vertex's page is its triangles' (a chart's vertex may lie on a page's edge).
        std::vector<int> page(inst.vertex_count, 0);
        for (uint32_t t = inst.first_triangle; t < inst.first_triangle + inst.triangle_count; ++t)
            for (int k = 0; k < 3; ++k) page[scene.triangles[t][k] - inst.first_vertex] = triangle_page(scene, t);
        VertexAttribute a{"TEXCOORD_1", 2, {}};
        a.values.resize(size_t(inst.vertex_count) * 2);
        for (uint32_t k = 0; k < inst.vertex_count; ++k) {
            const glm::vec2 uv = scene.uv1[inst.first_vertex + k];
            a.values[2 * k] = uv.x;
            a.values[2 * k + 1] = scene.lightmap_pages.v_on_page(uv.y, page[k]);
        }
        uv1[i].push_back(std::move(a));
    }
    return uv1;
}

}  // namespace

ColourImage unlit_look(const TexelSamples& texels, const std::vector<float>& lightmap_rgb) {
    if (lightmap_rgb.size() != size_t(texels.width) * size_t(texels.height) * 3)
        throw std::logic_error("the lightmap is not the atlas's size");
    std::vector<glm::vec3> radiance(size_t(texels.width) * size_t(texels.height), glm::vec3(0.0f));
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        const size_t t = texels.texels[i];
        const glm::vec3 e(lightmap_rgb[3 * t], lightmap_rgb[3 * t + 1], lightmap_rgb[3 * t + 2]);
        radiance[t] = texels.emission[i] + texels.albedo[i] * e;
    }
    dilate(texels, radiance);
    const float exposure = float(protocol::automatic_exposure(lightmap_rgb));
    ColourImage look{texels.width, texels.height, std::vector<uint8_t>(radiance.size() * 3)};
    // Every texel of the atlas through the curve (16 M of them at 4096²): on every core.
    parallel_for(radiance.size(), 4096, [&](size_t t) {
        const std::array<float, 3> shown =
            protocol::aces_filmic({radiance[t].r, radiance[t].g, radiance[t].b}, exposure);
        for (size_t c = 0; c < 3; ++c) look.rgb[3 * t + c] = protocol::encode_srgb8(shown[c]);
    });
    return look;
}

void write_lightmapped_glb(const std::filesystem::path& source_gltf, const Scene& scene,
                           const std::filesystem::path& out_glb, bool lights_baked) {
    write_glb(source_gltf, scene, lightmap_uvs(scene), out_glb, false, {}, lights_baked);
}

void write_lit_glb(const std::filesystem::path& source_gltf, const Scene& scene, const LitSceneMaps& maps,
                   const std::filesystem::path& out_glb) {
    write_glb(source_gltf, scene, lightmap_uvs(scene), out_glb, false, maps, maps.lightmap != nullptr);
}

void write_unlit_glb(const std::filesystem::path& source_gltf, const Scene& scene, const ColourImage& look,
                     const std::filesystem::path& out_glb) {
    write_glb(source_gltf, scene, lightmap_uvs(scene), out_glb, false, {}, true, &look);
}

void write_glb_with_vertex_attributes(const std::filesystem::path& source_gltf, const Scene& scene,
                                      const std::vector<std::vector<VertexAttribute>>& per_instance,
                                      const std::filesystem::path& out_glb, bool unlit_materials) {
    write_glb(source_gltf, scene, per_instance, out_glb, unlit_materials, {}, false);
}

}  // namespace lf
