// Primitives -> world-space triangles.
//
// Each (mesh, primitive) the scene places is read and checked once, in its
// own space; the instanced totals are then checked against the limits before
// the world-space arrays are allocated; then every placement is emitted.
#include "scene/gltf_build.h"

#include "bake_settings.h"

#include <glm/gtc/matrix_access.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numeric>
#include <type_traits>

namespace lf::gltf {

namespace {

struct LocalPrimitive {
    bool skipped = true;
    std::vector<glm::vec3> positions;
    std::vector<glm::vec3> normals;     // empty when the file has none
    std::vector<glm::vec2> uv0, uv1;    // empty when absent
    std::vector<glm::uvec3> triangles;  // counter-clockwise in the primitive's own space
    uint32_t material = 0;              // into Scene::materials
};

const char* mode_name(int mode) {
    switch (mode) {
    case TINYGLTF_MODE_POINTS: return "POINTS";
    case TINYGLTF_MODE_LINE: return "LINES";
    case TINYGLTF_MODE_LINE_LOOP: return "LINE_LOOP";
    case TINYGLTF_MODE_LINE_STRIP: return "LINE_STRIP";
    case TINYGLTF_MODE_TRIANGLES: return "TRIANGLES";
    case TINYGLTF_MODE_TRIANGLE_STRIP: return "TRIANGLE_STRIP";
    case TINYGLTF_MODE_TRIANGLE_FAN: return "TRIANGLE_FAN";
    default: return "unknown";
    }
}

std::string primitive_label(int mesh, int primitive) {
    return "mesh " + std::to_string(mesh) + " primitive " + std::to_string(primitive);
}

// Triangles from an index sequence, following glTF 2.0 §3.7.2.1. Triangles
// that repeat a vertex (strip restarts, padding) have no area and are dropped.
std::vector<glm::uvec3> assemble(int mode, const std::vector<uint32_t>& idx, size_t* leftover) {
    std::vector<glm::uvec3> tris;
    const size_t n = idx.size();
    auto emit = [&](uint32_t a, uint32_t b, uint32_t c) {
        if (a != b && b != c && a != c) tris.emplace_back(a, b, c);
    };
    *leftover = 0;
    if (mode == TINYGLTF_MODE_TRIANGLES) {
        tris.reserve(n / 3);
        for (size_t i = 0; i + 2 < n; i += 3) emit(idx[i], idx[i + 1], idx[i + 2]);
        *leftover = n % 3;
    } else if (mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
        // Every other triangle is flipped so that all keep the first one's winding.
        for (size_t i = 0; i + 2 < n; ++i) {
            if (i % 2 == 0) emit(idx[i], idx[i + 1], idx[i + 2]);
            else emit(idx[i], idx[i + 2], idx[i + 1]);
        }
    } else {  // TRIANGLE_FAN
        for (size_t i = 0; i + 2 < n; ++i) emit(idx[i + 1], idx[i + 2], idx[0]);
    }
    return tris;
}

void check_finite(const std::vector<glm::vec3>& v, int accessor, const char* semantic, const Errors& errors) {
    for (size_t i = 0; i < v.size(); ++i) {
        if (!std::isfinite(v[i].x) || !std::isfinite(v[i].y) || !std::isfinite(v[i].z)) {
            errors.fail("accessor", accessor,
                        std::string(semantic) + " element " + std::to_string(i) + " is not finite (NaN or infinity)");
        }
    }
}

void check_finite(const std::vector<glm::vec2>& v, int accessor, const char* semantic, const Errors& errors) {
    for (size_t i = 0; i < v.size(); ++i) {
        if (!std::isfinite(v[i].x) || !std::isfinite(v[i].y)) {
            errors.fail("accessor", accessor,
                        std::string(semantic) + " element " + std::to_string(i) + " is not finite (NaN or infinity)");
        }
    }
}

class GeometryBuilder {
public:
    GeometryBuilder(const tinygltf::Model& model, const AccessorReader& reader, const LoadLimits& limits,
                    const Errors& errors, Scene& scene, std::vector<std::string>* warnings)
        : model_(model), reader_(reader), limits_(limits), errors_(errors), scene_(scene), warnings_(warnings) {}

    void build(const std::vector<PlacedNode>& meshes);

private:
    // The accessor behind attribute `name`, or -1; checks that it exists.
    int attribute(const tinygltf::Primitive& p, const char* name, const std::string& where) const;
    template <typename T>
    std::vector<T> read_attribute(int accessor, const char* name, size_t vertices, const std::string& where) const;
    LocalPrimitive read_primitive(int mesh, int index);
    uint32_t default_material();
    void emit(const LocalPrimitive& prim, const PlacedNode& placed, int primitive_index);
    float lightmap_scale(const PlacedNode& placed) const;

    const tinygltf::Model& model_;
    const AccessorReader& reader_;
    const LoadLimits& limits_;
    const Errors& errors_;
    Scene& scene_;
    std::vector<std::string>* warnings_;
    int default_material_ = -1;
    uint64_t triangle_bound_ = 0;  // triangles the primitives read so far can make at most
};

int GeometryBuilder::attribute(const tinygltf::Primitive& p, const char* name, const std::string& where) const {
    const auto it = p.attributes.find(name);
    if (it == p.attributes.end()) return -1;
    const int accessor = it->second;
    if (accessor < 0 || size_t(accessor) >= model_.accessors.size()) {
        errors_.fail(where + ": attribute " + name + " refers to accessor " + std::to_string(accessor) +
                     ", which does not exist (the file has " + std::to_string(model_.accessors.size()) + " accessors)");
    }
    return accessor;
}

template <typename T>
std::vector<T> GeometryBuilder::read_attribute(int accessor, const char* name, size_t vertices,
                                               const std::string& where) const {
    std::vector<T> values;
    if constexpr (std::is_same_v<T, glm::vec3>) values = reader_.read_vec3(accessor, name);
    else values = reader_.read_vec2(accessor, name);
    if (values.size() != vertices) {
        errors_.fail(where + ": attribute " + name + " has " + std::to_string(values.size()) +
                     " elements, POSITION has " + std::to_string(vertices));
    }
    return values;
}

LocalPrimitive GeometryBuilder::read_primitive(int mesh, int index) {
    const tinygltf::Primitive& p = model_.meshes[size_t(mesh)].primitives[size_t(index)];
    const std::string where = primitive_label(mesh, index);
    LocalPrimitive prim;

    if (p.mode < TINYGLTF_MODE_POINTS || p.mode > TINYGLTF_MODE_TRIANGLE_FAN)
        errors_.fail(where + ": mode " + std::to_string(p.mode) + " is not a glTF primitive mode");
    if (p.mode < TINYGLTF_MODE_TRIANGLES) {
        warnings_->push_back(where + ": " + mode_name(p.mode) + " skipped (only triangles are baked)");
        return prim;
    }
    const int position = attribute(p, "POSITION", where);
    if (position < 0) {
        warnings_->push_back(where + ": no POSITION attribute; skipped");
        return prim;
    }
    if (!p.targets.empty()) warnings_->push_back(where + ": morph targets ignored (baked with the base shape)");

    // Every primitive read here is placed at least once, so the triangles its
    // indices could make count against the limit before anything is read.
    if (p.indices >= 0 && size_t(p.indices) >= model_.accessors.size())
        errors_.fail(where + ": indices accessor " + std::to_string(p.indices) + " does not exist");
    const uint64_t index_count = reader_.count(p.indices >= 0 ? p.indices : position);
    const uint64_t at_most =
        p.mode == TINYGLTF_MODE_TRIANGLES ? index_count / 3 : std::max<uint64_t>(index_count, 2) - 2;
    triangle_bound_ += at_most;
    if (triangle_bound_ > limits_.max_triangles) {
        errors_.fail(where + ": brings the scene to " + std::to_string(triangle_bound_) +
                     " triangles or more, over the limit of " + std::to_string(limits_.max_triangles));
    }

    prim.positions = reader_.read_vec3(position, "POSITION");
    check_finite(prim.positions, position, "POSITION", errors_);
    const size_t n = prim.positions.size();
    if (const int a = attribute(p, "NORMAL", where); a >= 0)
        prim.normals = read_attribute<glm::vec3>(a, "NORMAL", n, where);
    if (const int a = attribute(p, "TEXCOORD_0", where); a >= 0) {
        prim.uv0 = read_attribute<glm::vec2>(a, "TEXCOORD_0", n, where);
        check_finite(prim.uv0, a, "TEXCOORD_0", errors_);
    }
    if (const int a = attribute(p, "TEXCOORD_1", where); a >= 0) {
        prim.uv1 = read_attribute<glm::vec2>(a, "TEXCOORD_1", n, where);
        check_finite(prim.uv1, a, "TEXCOORD_1", errors_);
    }

    std::vector<uint32_t> indices;
    if (p.indices >= 0) {
        indices = reader_.read_indices(p.indices);
        for (size_t k = 0; k < indices.size(); ++k) {
            if (indices[k] >= n) {
                errors_.fail(where + ": index " + std::to_string(indices[k]) + " (element " + std::to_string(k) +
                             " of accessor " + std::to_string(p.indices) + ") is out of range for " +
                             std::to_string(n) + " vertices");
            }
        }
    } else {
        indices.resize(n);
        std::iota(indices.begin(), indices.end(), 0u);
    }
    size_t leftover = 0;
    prim.triangles = assemble(p.mode, indices, &leftover);
    if (leftover != 0)
        warnings_->push_back(where + ": " + std::to_string(leftover) +
                             " trailing indices do not make a triangle; ignored");
    if (prim.triangles.empty()) {
        warnings_->push_back(where + ": no triangles; skipped");
        return prim;
    }

    if (p.material >= 0 && size_t(p.material) >= model_.materials.size()) {
        errors_.fail(where + ": material " + std::to_string(p.material) + " does not exist (the file has " +
                     std::to_string(model_.materials.size()) + " materials)");
    }
    prim.material = p.material >= 0 ? uint32_t(p.material) : default_material();
    prim.skipped = false;
    return prim;
}

uint32_t GeometryBuilder::default_material() {
    if (default_material_ < 0) {
        Material m;
        m.name = "default (white)";
        scene_.materials.push_back(m);
        default_material_ = int(scene_.materials.size() - 1);
    }
    return uint32_t(default_material_);
}

void GeometryBuilder::build(const std::vector<PlacedNode>& meshes) {
    // 1. Read every placed (mesh, primitive) once.
    std::map<std::pair<int, int>, LocalPrimitive> primitives;
    for (const PlacedNode& placed : meshes) {
        const size_t count = model_.meshes[size_t(placed.item)].primitives.size();
        for (size_t p = 0; p < count; ++p) {
            const auto key = std::make_pair(placed.item, int(p));
            if (!primitives.count(key)) primitives.emplace(key, read_primitive(placed.item, int(p)));
        }
    }

    // 2. The instanced totals, before the world-space arrays are allocated.
    uint64_t triangles = 0, vertices = 0;
    for (const PlacedNode& placed : meshes) {
        const size_t count = model_.meshes[size_t(placed.item)].primitives.size();
        for (size_t p = 0; p < count; ++p) {
            const LocalPrimitive& prim = primitives.at({placed.item, int(p)});
            if (prim.skipped) continue;
            triangles += prim.triangles.size();
            vertices += prim.positions.size();
        }
    }
    if (triangles > limits_.max_triangles) {
        errors_.fail("the scene has " + std::to_string(triangles) +
                     " triangles after node instancing, over the limit of " + std::to_string(limits_.max_triangles));
    }
    // Vertex indices are 32-bit; and vertices no triangle uses cost memory too.
    const uint64_t max_vertices = std::min<uint64_t>(3 * limits_.max_triangles, std::numeric_limits<uint32_t>::max());
    if (vertices > max_vertices) {
        errors_.fail("the scene has " + std::to_string(vertices) +
                     " vertices after node instancing, over the limit of " + std::to_string(max_vertices));
    }

    // 3. Emit every placement.
    scene_.positions.reserve(size_t(vertices));
    scene_.normals.reserve(size_t(vertices));
    scene_.uv0.reserve(size_t(vertices));
    scene_.uv1.reserve(size_t(vertices));
    scene_.source_vertex.reserve(size_t(vertices));
    scene_.triangles.reserve(size_t(triangles));
    scene_.triangle_material.reserve(size_t(triangles));
    for (const PlacedNode& placed : meshes) {
        const size_t count = model_.meshes[size_t(placed.item)].primitives.size();
        for (size_t p = 0; p < count; ++p) {
            const LocalPrimitive& prim = primitives.at({placed.item, int(p)});
            if (!prim.skipped) emit(prim, placed, int(p));
        }
    }
}

// The node's extras.lightfarm_lightmap_scale, else its mesh's, else 1.
float GeometryBuilder::lightmap_scale(const PlacedNode& placed) const {
    constexpr const char* kKey = "lightfarm_lightmap_scale";
    const tinygltf::Node& node = model_.nodes[size_t(placed.node)];
    const tinygltf::Mesh& mesh = model_.meshes[size_t(placed.item)];
    const bool on_node = node.extras.IsObject() && node.extras.Has(kKey);
    const tinygltf::Value& extras = on_node ? node.extras : mesh.extras;
    if (!extras.IsObject() || !extras.Has(kKey)) return 1.0f;
    const tinygltf::Value& v = extras.Get(kKey);
    const double scale = v.IsNumber() ? v.GetNumberAsDouble() : std::nan("");
    if (!(scale >= 0.0 && scale <= protocol::kMaxLightmapScale))
        errors_.fail(on_node ? "node" : "mesh", on_node ? placed.node : placed.item,
                     std::string("extras.") + kKey +
                         " must be a number from 0 to 64 (the charts' texel density over the atlas's; 0: no "
                         "lightmap)");
    return float(scale);
}

void GeometryBuilder::emit(const LocalPrimitive& prim, const PlacedNode& placed, int primitive_index) {
    const glm::dmat4& world = placed.world;
    const glm::dmat3 linear(world);
    const bool mirrored = glm::determinant(linear) < 0.0;
    // Normals transform by the inverse transpose. Its columns are the cross
    // products of the matrix's columns divided by the determinant (the
    // cofactor matrix); using the cofactors times the determinant's sign keeps
    // the direction without dividing, so a singular transform is no error.
    const glm::dvec3 c0 = linear[0], c1 = linear[1], c2 = linear[2];
    const glm::dmat3 normal_matrix =
        glm::dmat3(glm::cross(c1, c2), glm::cross(c2, c0), glm::cross(c0, c1)) * (mirrored ? -1.0 : 1.0);

    PrimitiveInstance inst;
    inst.node = placed.node;
    inst.mesh = placed.item;
    inst.primitive = primitive_index;
    inst.first_vertex = uint32_t(scene_.positions.size());
    inst.vertex_count = uint32_t(prim.positions.size());
    inst.first_triangle = uint32_t(scene_.triangles.size());
    inst.triangle_count = uint32_t(prim.triangles.size());
    inst.has_uv1 = !prim.uv1.empty();
    inst.mirrored = mirrored;
    inst.lightmap_scale = lightmap_scale(placed);

    const uint32_t base = inst.first_vertex;
    for (size_t k = 0; k < prim.positions.size(); ++k) {
        const glm::vec3 p(world * glm::dvec4(glm::dvec3(prim.positions[k]), 1.0));
        if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
            errors_.fail("node", placed.node,
                         "its transform takes mesh " + std::to_string(placed.item) + " to non-finite positions");
        }
        scene_.positions.push_back(p);
        scene_.bounds.extend(p);
        scene_.uv0.push_back(prim.uv0.empty() ? glm::vec2(0.0f) : prim.uv0[k]);
        scene_.uv1.push_back(prim.uv1.empty() ? glm::vec2(0.0f) : prim.uv1[k]);
        scene_.source_vertex.push_back(uint32_t(k));
    }
    for (const glm::uvec3& t : prim.triangles) {
        // Mirroring turns counter-clockwise into clockwise; swapping two
        // corners turns it back, so the front stays the front.
        scene_.triangles.push_back(mirrored ? glm::uvec3(t.x, t.z, t.y) + base : t + base);
        scene_.triangle_material.push_back(prim.material);
    }

    // File normals go through the normal matrix. Where the file has none, or
    // one is zero or not finite, the area-weighted normal of the world-space
    // triangles around the vertex takes its place.
    auto unit = [](glm::vec3 v) {
        const float length = glm::length(v);
        return std::isfinite(length) && length > 0.0f ? v / length : glm::vec3(0.0f);  // zero: none yet
    };
    bool incomplete = prim.normals.empty();
    for (size_t k = 0; k < prim.positions.size(); ++k) {
        const glm::vec3 n =
            prim.normals.empty() ? glm::vec3(0.0f) : unit(glm::vec3(normal_matrix * glm::dvec3(prim.normals[k])));
        incomplete = incomplete || n == glm::vec3(0.0f);
        scene_.normals.push_back(n);
    }
    if (incomplete) {
        std::vector<glm::vec3> computed(prim.positions.size(), glm::vec3(0.0f));
        for (uint32_t t = inst.first_triangle; t < inst.first_triangle + inst.triangle_count; ++t) {
            const glm::uvec3& tri = scene_.triangles[t];
            const glm::vec3 n = glm::cross(scene_.positions[tri.y] - scene_.positions[tri.x],
                                           scene_.positions[tri.z] - scene_.positions[tri.x]);  // length = 2 x area
            for (int c = 0; c < 3; ++c) computed[tri[c] - base] += n;
        }
        for (size_t k = 0; k < prim.positions.size(); ++k) {
            glm::vec3& n = scene_.normals[base + k];
            if (n == glm::vec3(0.0f)) n = unit(computed[k]);
            // A vertex no triangle with area uses still needs a unit normal.
            if (n == glm::vec3(0.0f)) n = glm::vec3(0.0f, 0.0f, 1.0f);
        }
    }
    scene_.instances.push_back(inst);
}

}  // namespace

void add_geometry(const tinygltf::Model& model, const std::vector<PlacedNode>& meshes, const AccessorReader& reader,
                  const LoadLimits& limits, const Errors& errors, Scene& scene, std::vector<std::string>* warnings) {
    GeometryBuilder(model, reader, limits, errors, scene, warnings).build(meshes);
}

}  // namespace lf::gltf
