// The glTF loader: every malformed file refused with one specific line, the
// shared scenes loaded with the right counts, and small generated files that
// pin down transforms, winding, primitive modes, accessors, materials, lights.
#include "gltf_test_files.h"

#include "scene/gltf_loader.h"
#include "scene/scene_summary.h"
#include "util/hash.h"
#include "scene_builders.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/quaternion.hpp>
#include <glm/gtc/type_ptr.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cmath>
#include <fstream>
#include <iterator>
#include <map>
#include <random>

namespace lf {
namespace {

using nlohmann::json;
using test::feature_file;
using test::GltfWriter;
using test::kGreyPng;
using test::kQuad;
using test::kQuadIndices;
using test::kRedBluePng;
using test::primitive;
using test::quad_file;
using test::TempDir;
using test::textured_quad;
namespace fs = std::filesystem;

const fs::path kScenes = LIGHTFARM_EXAMPLES;

// The SceneError message of loading `file`, or a test failure if it loads.
std::string load_error(const fs::path& file, const LoadLimits& limits = {}) {
    try {
        load_scene(file, limits);
    } catch (const SceneError& e) {
        return e.what();
    } catch (const std::exception& e) {
        ADD_FAILURE() << file << ": threw a " << typeid(e).name() << " instead of SceneError: " << e.what();
        return e.what();
    }
    ADD_FAILURE() << file << ": loaded, but should have been refused";
    return {};
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

bool has_warning(const Scene& scene, const std::string& part) {
    for (const std::string& w : scene.warnings) {
        if (contains(w, part)) return true;
    }
    return false;
}

void expect_near(glm::vec3 a, glm::vec3 b, float tolerance = 1e-5f) {
    EXPECT_NEAR(a.x, b.x, tolerance);
    EXPECT_NEAR(a.y, b.y, tolerance);
    EXPECT_NEAR(a.z, b.z, tolerance);
}

// ============================================================================
// Malformed files
// ============================================================================

constexpr const char* kCanary = "/tmp/lightfarm-canary";

TEST(BadScenes, EveryFileIsRefusedWithOneSpecificLine) {
    std::vector<fs::path> files;
    for (const fs::directory_entry& entry : fs::directory_iterator(kScenes / "bad")) {
        if (entry.is_regular_file()) files.push_back(entry.path());
    }
    std::sort(files.begin(), files.end());
    for (const fs::path& file : files) {
        const std::string name = file.filename().string();
        SCOPED_TRACE(name);
        std::error_code ec;
        fs::remove(kCanary, ec);
        const std::string message = load_error(file);
        std::printf("    %s\n", message.c_str());  // the messages, for a reader of the test log
        EXPECT_EQ(message.find('\n'), std::string::npos) << message;
        EXPECT_EQ(message.rfind(name + ": ", 0), 0u) << "does not start with the file name: " << message;
        // Specific: more than the file name and a generic word.
        EXPECT_GT(message.size(), name.size() + 15) << message;
        EXPECT_FALSE(contains(message, "unknown error")) << message;
        EXPECT_FALSE(fs::exists(kCanary)) << "loading " << name << " ran a shell command";
    }
    EXPECT_GE(files.size(), 31u);
}

TEST(BadScenes, KeyFilesSayWhatIsWrong) {
    // File -> words its message must contain (any one of them).
    const std::map<std::string, std::vector<std::string>> expected = {
        {"required_draco.gltf", {"KHR_draco_mesh_compression"}},
        {"required_meshopt.gltf", {"EXT_meshopt_compression"}},
        {"image_bomb.gltf", {"65535"}},
        {"node_cycle.gltf", {"cycle"}},
        {"self_child.gltf", {"cycle"}},
        {"index_out_of_range.gltf", {"index 99999"}},
        {"accessor_out_of_view.gltf", {"accessor 0: byteOffset+length 12000 exceeds bufferView 0 length 36"}},
        {"view_out_of_buffer.gltf", {"bufferView 0: byteOffset 0 + byteLength 4096 exceeds buffer 0 length 48"}},
        {"stride_too_small.gltf", {"byteStride 4 is smaller than the element size 12"}},
        {"huge_count.gltf", {"accessor 0"}},
        {"nan_positions.gltf", {"not finite"}},
        {"negative_offset.gltf", {"bufferView 0: byteOffset"}},
        {"bad_base64.gltf", {"base64"}},
        {"bad_component_type.gltf", {"accessor 1: indices must be"}},
        {"bad_type_string.gltf", {"VEC7"}},
        {"missing_accessor.gltf", {"accessor 42"}},
        {"buffer_shorter_than_declared.gltf", {"buffer 0: data: URI holds 48 bytes, byteLength says 4000"}},
        {"uri_absolute.gltf", {"absolute"}},
        {"uri_parent_escape.gltf", {"leaves the scene directory"}},
        {"image_uri_escape.gltf", {"image 0"}},
        {"uri_missing_file.gltf", {"not found"}},
        {"uri_shell_expansion.gltf", {"not found"}},
        {"wrong_version.gltf", {"version \"1.0\""}},
        {"no_asset.gltf", {"asset"}},
        {"not_json.gltf", {"not valid JSON"}},
        {"empty.gltf", {"empty"}},
        {"glb_bad_magic.glb", {"magic"}},
        {"glb_version1.glb", {"version 1"}},
        {"glb_length_lies.glb", {"length says 1000000000 bytes"}},
        {"glb_chunk_overflow.glb", {"GLB chunk 0"}},
        {"glb_truncated.glb", {"length"}},
    };
    for (const auto& [file, words] : expected) {
        SCOPED_TRACE(file);
        const std::string message = load_error(kScenes / "bad" / file);
        bool found = false;
        for (const std::string& w : words) found = found || contains(message, w);
        EXPECT_TRUE(found) << message;
    }
}

TEST(BadScenes, ShellExpansionRunsNothing) {
    std::error_code ec;
    fs::remove(kCanary, ec);
    ASSERT_FALSE(fs::exists(kCanary));
    load_error(kScenes / "bad" / "uri_shell_expansion.gltf");
    EXPECT_FALSE(fs::exists(kCanary));
}

TEST(BadScenes, ImageBombIsRefusedFromItsHeader) {
    // 65535² RGBA would be 16 GiB; the message says which limit it broke.
    const std::string message = load_error(kScenes / "bad" / "image_bomb.gltf");
    EXPECT_TRUE(contains(message, "65535x65535")) << message;
    EXPECT_TRUE(contains(message, "8192")) << message;
}

// ============================================================================
// The shared scenes
// ============================================================================

// What every loaded Scene must satisfy, whatever the file.
void expect_consistent(const Scene& s) {
    const size_t v = s.positions.size();
    ASSERT_EQ(s.normals.size(), v);
    ASSERT_EQ(s.uv0.size(), v);
    ASSERT_EQ(s.uv1.size(), v);
    ASSERT_EQ(s.source_vertex.size(), v);
    ASSERT_EQ(s.triangle_material.size(), s.triangles.size());
    for (const PrimitiveInstance& inst : s.instances) {
        ASSERT_LE(uint64_t(inst.first_vertex) + inst.vertex_count, v);
        ASSERT_LE(uint64_t(inst.first_triangle) + inst.triangle_count, s.triangles.size());
        for (uint32_t t = inst.first_triangle; t < inst.first_triangle + inst.triangle_count; ++t) {
            for (int c = 0; c < 3; ++c) {
                ASSERT_GE(s.triangles[t][c], inst.first_vertex);
                ASSERT_LT(s.triangles[t][c], inst.first_vertex + inst.vertex_count);
            }
        }
        for (uint32_t k = 0; k < inst.vertex_count; ++k) ASSERT_EQ(s.source_vertex[inst.first_vertex + k], k);
    }
    for (uint32_t m : s.triangle_material) ASSERT_LT(m, s.materials.size());
    for (const Material& m : s.materials) {
        ASSERT_LT(m.base_color_texture, int(s.textures.size()));
        ASSERT_LT(m.emissive_texture, int(s.textures.size()));
    }
    for (size_t i = 0; i < v; ++i) {
        ASSERT_NEAR(glm::length(s.normals[i]), 1.0f, 1e-4f) << "vertex " << i;
        ASSERT_TRUE(glm::all(glm::greaterThanEqual(s.positions[i], s.bounds.lo)));
        ASSERT_TRUE(glm::all(glm::lessThanEqual(s.positions[i], s.bounds.hi)));
    }
}

struct SharedScene {
    const char* file;
    size_t triangles;
    bool all_uv1;
    size_t point_lights, directional_lights;
    bool emissive;        // some triangle emits
    const char* warning;  // a warning it must give, or nullptr
};

class SharedScenes : public testing::TestWithParam<SharedScene> {};

TEST_P(SharedScenes, LoadWithTheDocumentedCounts) {
    const SharedScene& expected = GetParam();
    const auto start = std::chrono::steady_clock::now();
    const Scene scene = load_scene(kScenes / expected.file);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::printf("    %s: %zu triangles in %.3f s\n", expected.file, scene.triangle_count(), seconds);
    RecordProperty("load_seconds", std::to_string(seconds));

    EXPECT_EQ(scene.triangle_count(), expected.triangles);
    EXPECT_EQ(scene.all_have_lightmap_uvs(), expected.all_uv1);
    size_t point = 0, directional = 0;
    for (const PunctualLight& l : scene.lights) {
        point += l.type == PunctualLight::Type::Point;
        directional += l.type == PunctualLight::Type::Directional;
    }
    EXPECT_EQ(point, expected.point_lights);
    EXPECT_EQ(directional, expected.directional_lights);
    EXPECT_EQ(scene.emissive_triangle_count() > 0, expected.emissive);
    if (expected.warning != nullptr) {
        EXPECT_TRUE(has_warning(scene, expected.warning)) << protocol::to_json(summarize(scene)).dump();
    }
    const bool lit = expected.emissive || expected.point_lights + expected.directional_lights > 0;
    EXPECT_EQ(has_warning(scene, "no light"), !lit);
    EXPECT_FALSE(has_warning(scene, "no geometry with area"));
    expect_consistent(scene);
    // A loader should be quick even for the big interiors; generous for sanitizer builds.
    EXPECT_LT(seconds, 30.0);
}

INSTANTIATE_TEST_SUITE_P(
    All, SharedScenes,
    testing::Values(SharedScene{"cornell_box.gltf", 32, true, 0, 0, true, nullptr},
                    SharedScene{"flower.glb", 2611, true, 0, 0, false, nullptr},
                    SharedScene{"monkey.glb", 5950, false, 1, 0, false, nullptr},
                    SharedScene{"packuv.glb", 3240, false, 0, 0, false, nullptr},
                    SharedScene{"random.glb", 5065, false, 0, 0, false, "KHR_materials_unlit"},
                    SharedScene{"noisy.glb", 5950, false, 0, 0, false, nullptr},
                    // SOURCES.md mentions an emissive panel; the file has none (one grey material).
                    SharedScene{"spheres.glb", 245764, false, 0, 1, false, nullptr},
                    SharedScene{"real/wooden_staircase/wooden_staircase.gltf", 262663, false, 0, 0, true,
                                "KHR_materials_transmission"},
                    SharedScene{"real/breakfast_room/breakfast_room.gltf", 269538, false, 0, 0, false, "no light"},
                    SharedScene{"real/grey_white_room/grey_white_room.gltf", 143163, false, 0, 0, false, nullptr}),
    [](const testing::TestParamInfo<SharedScene>& info) {
        std::string name = fs::path(info.param.file).stem().string();
        std::replace(name.begin(), name.end(), '-', '_');
        return name;
    });

// spheres.glb is made by examples/make_spheres.py, not stored: the bytes it
// writes are the file the figures in docs/BENCHMARKS.md were measured on
// (it was stored until 2026-12-07; sha256 23d683f6…, 6,397,404 bytes: the
// script reproduces it bit for bit, and this hash of it guards that).
constexpr uint64_t kSpheresHash = 0x1db21e426b0ea630ull;  // hash_bytes of the stored file

TEST(SharedScenes, SpheresAreTheFileTheFiguresWereMeasuredOn) {
    std::ifstream in(kScenes / "spheres.glb", std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_EQ(bytes.size(), 6397404u);
    EXPECT_EQ(hash_bytes(bytes.data(), bytes.size()), kSpheresHash);
}

TEST(SharedScenes, CornellBoxLightIsTheDocumentedRadiance) {
    const Scene scene = load_scene(kScenes / "cornell_box.gltf");
    // emissiveFactor (1, 0.706, 0.235) x KHR_materials_emissive_strength 17.
    bool found = false;
    for (const Material& m : scene.materials) {
        if (!m.is_emissive()) continue;
        found = true;
        expect_near(m.emission, glm::vec3(17.0f, 12.0f, 4.0f), 0.01f);
    }
    EXPECT_TRUE(found);
    EXPECT_EQ(scene.emissive_triangle_count(), 2u);

    const json summary = protocol::to_json(summarize(scene));
    EXPECT_EQ(summary["triangles"], 32);
    EXPECT_EQ(summary["emissive_triangles"], 2);
    EXPECT_EQ(summary["primitive_instances"], scene.instances.size());
    EXPECT_EQ(summary["meshes"], 4);
    EXPECT_EQ(summary["lightmap_uvs"]["all_primitives"], true);
    EXPECT_EQ(summary["lightmap_uvs"]["primitives_with_texcoord_1"], scene.instances.size());
    EXPECT_EQ(summary["textures"], 0);
    EXPECT_NEAR(summary["bounds"]["hi"][0].get<double>(), 0.556, 1e-3);  // Cornell's 556 mm floor
    EXPECT_GT(summary["surface_area"].get<double>(), 1.0);
    EXPECT_TRUE(summary["warnings"].empty());
    EXPECT_NE(format_summary(scene).find("32 triangles"), std::string::npos);
    // 16 quads, each its own primitive; every one with TEXCOORD_1 in [0, 1].
    for (const glm::vec2& uv : scene.uv1) {
        EXPECT_GE(uv.x, 0.0f);
        EXPECT_LE(uv.x, 1.0f);
    }
}

TEST(SharedScenes, TexturedInteriorHasLinearTextures) {
    const Scene scene = load_scene(kScenes / "real/wooden_staircase/wooden_staircase.gltf");
    ASSERT_FALSE(scene.textures.empty());
    for (const Texture& t : scene.textures) {
        EXPECT_GT(t.width, 0);
        EXPECT_LE(t.width, 8192);
        EXPECT_EQ(t.texels.size(), size_t(t.width) * size_t(t.height));
    }
    const json summary = protocol::to_json(summarize(scene));
    EXPECT_EQ(summary["triangles"], 262663);
    EXPECT_EQ(summary["textures"], scene.textures.size());
    EXPECT_EQ(summary["max_texture_size"], 512);
    EXPECT_GT(summary["surface_area"].get<double>(), 1.0);
    EXPECT_FALSE(format_summary(scene).empty());
}

// ============================================================================
// Generated files
// ============================================================================

Scene load_written(const GltfWriter& w, const TempDir& dir, const std::string& name = "scene.gltf") {
    return load_scene(w.write(dir.path(), name));
}

TEST(GeneratedScenes, TrsAndMatrixGiveTheSameWorldPositions) {
    GltfWriter w;
    const int mesh = w.mesh(primitive(w.vec3(kQuad), w.scalars(kQuadIndices, test::kUnsignedShort)));
    const glm::dvec3 t(1, 2, 3), scale(2, 0.5, 3);
    const glm::dquat r = glm::angleAxis(0.7, glm::normalize(glm::dvec3(1, 2, -0.5)));
    const glm::dmat4 m = glm::translate(glm::dmat4(1.0), t) * glm::mat4_cast(r) * glm::scale(glm::dmat4(1.0), scale);
    std::vector<double> matrix(glm::value_ptr(m), glm::value_ptr(m) + 16);
    const int trs = w.add("nodes", {{"mesh", mesh},
                                    {"translation", {t.x, t.y, t.z}},
                                    {"rotation", {r.x, r.y, r.z, r.w}},
                                    {"scale", {scale.x, scale.y, scale.z}}});
    const int mat = w.add("nodes", {{"mesh", mesh}, {"matrix", matrix}});
    w.scene({trs, mat});
    TempDir dir;
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.instances.size(), 2u);
    for (size_t k = 0; k < kQuad.size(); ++k) {
        const glm::vec3 expected(m * glm::dvec4(glm::dvec3(kQuad[k]), 1.0));
        expect_near(s.positions[s.instances[0].first_vertex + k], expected);
        expect_near(s.positions[s.instances[1].first_vertex + k], expected);
    }
    expect_consistent(s);
}

TEST(GeneratedScenes, NestedTransformsCompose) {
    GltfWriter w;
    const int mesh = w.mesh(primitive(w.vec3(kQuad), w.scalars(kQuadIndices, test::kUnsignedShort)));
    const int child = w.add("nodes", {{"mesh", mesh}, {"translation", {1, 0, 0}}});
    const int parent = w.add("nodes", {{"children", {child}}, {"scale", {2, 2, 2}}, {"translation", {0, 0, 5}}});
    w.scene({parent});
    TempDir dir;
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.instances.size(), 1u);
    EXPECT_EQ(s.instances[0].node, child);
    // parent(child(p)) = 2 * (p + (1,0,0)) + (0,0,5)
    expect_near(s.positions[2], glm::vec3(4, 2, 5));
}

TEST(GeneratedScenes, MirroredNodeKeepsFrontFaces) {
    GltfWriter w;
    const int positions = w.vec3(kQuad);
    const int normals = w.vec3(std::vector<glm::vec3>(4, glm::vec3(0, 0, 1)));
    const int indices = w.scalars(kQuadIndices, test::kUnsignedShort);
    const int mesh = w.mesh({{"attributes", {{"POSITION", positions}, {"NORMAL", normals}}}, {"indices", indices}});
    const int plain = w.add("nodes", {{"mesh", mesh}});
    const int mirrored = w.add("nodes", {{"mesh", mesh}, {"scale", {-1, 1, 1}}});
    const int flipped = w.add("nodes", {{"mesh", mesh}, {"scale", {1, 1, -1}}, {"translation", {0, 0, 2}}});
    w.scene({plain, mirrored, flipped});
    TempDir dir;
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.instances.size(), 3u);
    EXPECT_FALSE(s.instances[0].mirrored);
    EXPECT_TRUE(s.instances[1].mirrored);
    EXPECT_TRUE(s.instances[2].mirrored);
    // The file normal is +Z everywhere; x-mirroring keeps it, z-mirroring turns it to -Z.
    expect_near(s.normals[s.instances[1].first_vertex], glm::vec3(0, 0, 1));
    expect_near(s.normals[s.instances[2].first_vertex], glm::vec3(0, 0, -1));
    // The triangle's front (its geometric normal) agrees with its vertex normals.
    for (size_t t = 0; t < s.triangles.size(); ++t) {
        const glm::vec3 n = s.geometric_normal(t);
        for (int c = 0; c < 3; ++c) EXPECT_GT(glm::dot(n, s.normals[s.triangles[t][c]]), 0.999f) << "triangle " << t;
    }
    expect_consistent(s);
}

TEST(GeneratedScenes, StripsAndFansKeepOneWinding) {
    GltfWriter w;
    // A strip zig-zagging along x, and a fan around a pentagon: all facing +Z.
    const std::vector<glm::vec3> strip = {{0, 0, 0}, {0, 1, 0}, {1, 0, 0}, {1, 1, 0}, {2, 0, 0}, {2, 1, 0}};
    std::vector<glm::vec3> fan = {{0, 0, 0}};
    for (int k = 0; k <= 4; ++k) fan.emplace_back(std::cos(k * 0.5), std::sin(k * 0.5), 0.0);
    // Taken in order 0,1,2 the first triangle would be clockwise (1 above 0, 2 right
    // of 0), so the strip starts from vertex 1: (1,0,3) is counter-clockwise.
    const std::vector<uint8_t> strip_ccw = {1, 0, 3, 2, 5, 4};
    const int strip_mesh = w.mesh(primitive(w.vec3(strip), w.scalars(strip_ccw, test::kUnsignedByte), {{"mode", 5}}));
    const int fan_mesh = w.mesh(primitive(w.vec3(fan), -1, {{"mode", 6}}));  // not indexed
    w.scene({w.add("nodes", {{"mesh", strip_mesh}}), w.add("nodes", {{"mesh", fan_mesh}})});
    TempDir dir;
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.instances.size(), 2u);
    EXPECT_EQ(s.instances[0].triangle_count, 4u);  // n - 2
    EXPECT_EQ(s.instances[1].triangle_count, 4u);
    for (size_t t = 0; t < s.triangles.size(); ++t) {
        expect_near(s.geometric_normal(t), glm::vec3(0, 0, 1));
        EXPECT_GT(s.triangle_area(t), 0.0f);
    }
    // No normals in the file: computed, and +Z for a flat mesh.
    for (const glm::vec3& n : s.normals) expect_near(n, glm::vec3(0, 0, 1));
}

TEST(GeneratedScenes, AllIndexTypesGiveTheSameTriangles) {
    GltfWriter w;
    const int positions = w.vec3(kQuad);
    const std::vector<uint8_t> u8(kQuadIndices.begin(), kQuadIndices.end());
    const std::vector<uint32_t> u32(kQuadIndices.begin(), kQuadIndices.end());
    const int m8 = w.mesh(primitive(positions, w.scalars(u8, test::kUnsignedByte)));
    const int m16 = w.mesh(primitive(positions, w.scalars(kQuadIndices, test::kUnsignedShort)));
    const int m32 = w.mesh(primitive(positions, w.scalars(u32, test::kUnsignedInt)));
    w.scene({w.add("nodes", {{"mesh", m8}}), w.add("nodes", {{"mesh", m16}}), w.add("nodes", {{"mesh", m32}})});
    TempDir dir;
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.triangles.size(), 6u);
    for (size_t i = 0; i < 3; ++i) {
        const PrimitiveInstance& inst = s.instances[i];
        EXPECT_EQ(s.triangles[inst.first_triangle] - glm::uvec3(inst.first_vertex), glm::uvec3(0, 1, 2));
        EXPECT_EQ(s.triangles[inst.first_triangle + 1] - glm::uvec3(inst.first_vertex), glm::uvec3(0, 2, 3));
    }
}

TEST(GeneratedScenes, ByteStrideInterleavedAttributes) {
    // POSITION and NORMAL interleaved in one view: stride 24.
    std::vector<float> interleaved;
    for (const glm::vec3& p : kQuad) interleaved.insert(interleaved.end(), {p.x, p.y, p.z, 0.0f, 0.0f, 1.0f});
    GltfWriter w;
    const int view = w.view(interleaved.data(), interleaved.size() * sizeof(float), 24);
    const int pos = w.accessor(view, test::kFloat, 4, "VEC3");
    const int nrm = w.accessor(view, test::kFloat, 4, "VEC3", false, 12);
    const int mesh = w.mesh({{"attributes", {{"POSITION", pos}, {"NORMAL", nrm}}},
                             {"indices", w.scalars(kQuadIndices, test::kUnsignedShort)}});
    w.scene({w.add("nodes", {{"mesh", mesh}})});
    TempDir dir;
    const Scene s = load_written(w, dir);
    for (size_t k = 0; k < 4; ++k) {
        expect_near(s.positions[k], kQuad[k]);
        expect_near(s.normals[k], glm::vec3(0, 0, 1));
    }
}

TEST(GeneratedScenes, SparseAccessorOverridesBaseValues) {
    GltfWriter w;
    const int positions = w.vec3(kQuad);
    // Vertex 2 moved to (3, 3, 0) by a sparse substitution.
    const std::vector<uint8_t> sparse_indices = {2};
    const std::vector<glm::vec3> sparse_values = {{3, 3, 0}};
    const int iv = w.view(sparse_indices.data(), 1);
    const int vv = w.view(sparse_values.data(), sizeof(glm::vec3));
    w.accessor_json(positions)["sparse"] = {{"count", 1},
                                            {"indices", {{"bufferView", iv}, {"componentType", test::kUnsignedByte}}},
                                            {"values", {{"bufferView", vv}}}};
    // And an accessor with no bufferView at all: zeros plus sparse values.
    const int zeros = w.accessor(-1, test::kFloat, 4, "VEC3");
    w.accessor_json(zeros)["sparse"] = w.accessor_json(positions)["sparse"];
    const int indices = w.scalars(kQuadIndices, test::kUnsignedShort);
    w.scene({w.add("nodes", {{"mesh", w.mesh(primitive(positions, indices))}}),
             w.add("nodes", {{"mesh", w.mesh(primitive(zeros, indices))}})});
    TempDir dir;
    const Scene s = load_written(w, dir);
    expect_near(s.positions[0], kQuad[0]);
    expect_near(s.positions[2], glm::vec3(3, 3, 0));
    expect_near(s.positions[3], kQuad[3]);
    expect_near(s.positions[4 + 1], glm::vec3(0, 0, 0));
    expect_near(s.positions[4 + 2], glm::vec3(3, 3, 0));
}

TEST(GeneratedScenes, NormalizedIntegerTexcoords) {
    GltfWriter w;
    const std::vector<uint16_t> uv0 = {0, 0, 65535, 0, 65535, 65535, 32768, 65535};
    const std::vector<uint8_t> uv1 = {0, 0, 255, 0, 255, 255, 51, 255};
    const int mesh = w.mesh({{"attributes",
                              {{"POSITION", w.vec3(kQuad)},
                               {"TEXCOORD_0", w.scalars(uv0, test::kUnsignedShort, true, "VEC2")},
                               {"TEXCOORD_1", w.scalars(uv1, test::kUnsignedByte, true, "VEC2")}}},
                             {"indices", w.scalars(kQuadIndices, test::kUnsignedShort)}});
    w.scene({w.add("nodes", {{"mesh", mesh}})});
    TempDir dir;
    const Scene s = load_written(w, dir);
    EXPECT_TRUE(s.all_have_lightmap_uvs());
    EXPECT_NEAR(s.uv0[2].x, 1.0f, 1e-6f);
    EXPECT_NEAR(s.uv0[3].x, 32768.0f / 65535.0f, 1e-6f);
    EXPECT_NEAR(s.uv1[3].x, 0.2f, 1e-6f);
    EXPECT_NEAR(s.uv1[2].y, 1.0f, 1e-6f);
}

TEST(GeneratedScenes, UnnormalizedIntegerTexcoordsAreRefused) {
    GltfWriter w;
    const std::vector<uint16_t> uv0 = {0, 0, 1, 0, 1, 1, 0, 1};
    const int mesh =
        w.mesh({{"attributes",
                 {{"POSITION", w.vec3(kQuad)}, {"TEXCOORD_0", w.scalars(uv0, test::kUnsignedShort, false, "VEC2")}}}});
    w.scene({w.add("nodes", {{"mesh", mesh}})});
    TempDir dir;
    const std::string message = load_error(w.write(dir.path(), "uv.gltf"));
    EXPECT_TRUE(contains(message, "uv.gltf: accessor 1: TEXCOORD_0 must be VEC2 FLOAT or normalized")) << message;
}

TEST(GeneratedScenes, MissingNormalsAreAreaWeighted) {
    // Vertex 0 is shared by a large triangle facing +Z (area 2) and a small
    // one facing +X (area 0.125): its normal leans 1:16 towards +X.
    const std::vector<glm::vec3> p = {{0, 0, 0}, {2, 0, 0}, {0, 2, 0}, {0, 0.5f, 0}, {0, 0, -0.5f}};
    const std::vector<uint8_t> idx = {0, 1, 2, 0, 4, 3};
    GltfWriter w;
    w.scene({w.add("nodes", {{"mesh", w.mesh(primitive(w.vec3(p), w.scalars(idx, test::kUnsignedByte)))}})});
    TempDir dir;
    const Scene s = load_written(w, dir);
    expect_near(s.geometric_normal(0), glm::vec3(0, 0, 1));
    expect_near(s.geometric_normal(1), glm::vec3(1, 0, 0));
    expect_near(s.normals[0], glm::normalize(glm::vec3(0.125f, 0, 2)));
    expect_near(s.normals[1], glm::vec3(0, 0, 1));
    expect_near(s.normals[4], glm::vec3(1, 0, 0));
}

TEST(GeneratedScenes, EmissiveStrengthMultipliesTheFactor) {
    GltfWriter w;
    w.add("materials", {{"emissiveFactor", {1.0, 0.5, 0.25}},
                        {"doubleSided", true},
                        {"extensions", {{"KHR_materials_emissive_strength", {{"emissiveStrength", 4.0}}}}}});
    w.doc["extensionsUsed"] = {"KHR_materials_emissive_strength"};
    w.doc["extensionsRequired"] = {"KHR_materials_emissive_strength"};
    w.scene({w.add("nodes", {{"mesh", w.mesh(primitive(w.vec3(kQuad), w.scalars(kQuadIndices, test::kUnsignedShort),
                                                       {{"material", 0}}))}})});
    TempDir dir;
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.materials.size(), 1u);  // no default material: every primitive has one
    expect_near(s.materials[0].emission, glm::vec3(4, 2, 1));
    EXPECT_TRUE(s.materials[0].double_sided);
    EXPECT_EQ(s.emissive_triangle_count(), 2u);
    EXPECT_FALSE(has_warning(s, "no light"));
    EXPECT_TRUE(s.warnings.empty()) << s.warnings.front();
}

// See-through materials (issue #35): alphaMode and alphaCutoff,
// KHR_materials_transmission's factor and KHR_materials_volume's absorption
// read into the Material, and a note per material saying how light passes
// it; an opaque material gets none. Absorption: attenuationColor per
// attenuationDistance: -ln(attenuationColor) / attenuationDistance per metre.
TEST(GeneratedScenes, SeeThroughMaterialsAreReadAndSaidHowLightPasses) {
    GltfWriter w;
    w.add("materials", {{"name", "leaves"}, {"alphaMode", "MASK"}, {"alphaCutoff", 0.3}});
    w.add("materials", {{"name", "curtain"},
                        {"alphaMode", "BLEND"},
                        {"pbrMetallicRoughness", {{"baseColorFactor", {1.0, 1.0, 1.0, 0.4}}}}});
    w.add("materials",
          {{"name", "window"}, {"extensions", {{"KHR_materials_transmission", {{"transmissionFactor", 0.9}}}}}});
    w.add("materials", {{"name", "wall"}, {"alphaMode", "OPAQUE"}});
    w.add("materials",
          {{"name", "bottle"},
           {"extensions",
            {{"KHR_materials_transmission", {{"transmissionFactor", 1.0}}},
             {"KHR_materials_volume",
              {{"thicknessFactor", 0.5}, {"attenuationDistance", 0.25}, {"attenuationColor", {0.25, 0.5, 1.0}}}}}}});
    w.doc["extensionsUsed"] = {"KHR_materials_transmission", "KHR_materials_volume"};
    std::vector<int> nodes;
    for (int m = 0; m < 5; ++m)
        nodes.push_back(
            w.add("nodes", {{"mesh", w.mesh(primitive(w.vec3(kQuad), w.scalars(kQuadIndices, test::kUnsignedShort),
                                                      {{"material", m}}))}}));
    w.scene(nodes);
    TempDir dir;
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.materials.size(), 5u);
    EXPECT_EQ(s.materials[0].alpha_mode, Material::AlphaMode::Mask);
    EXPECT_FLOAT_EQ(s.materials[0].alpha_cutoff, 0.3f);
    EXPECT_EQ(s.materials[1].alpha_mode, Material::AlphaMode::Blend);
    EXPECT_FLOAT_EQ(s.materials[1].base_color.a, 0.4f);
    EXPECT_FLOAT_EQ(s.materials[2].transmission, 0.9f);
    EXPECT_FALSE(s.materials[3].is_see_through());
    EXPECT_FLOAT_EQ(s.materials[4].transmission, 1.0f);
    expect_near(s.materials[4].attenuation, -glm::log(glm::vec3(0.25f, 0.5f, 1.0f)) / 0.25f);
    EXPECT_FLOAT_EQ(s.materials[4].thickness, 0.5f);
    EXPECT_TRUE(s.materials[4].has_volume());
    // One quad closes no volume: its absorption is the thin approximation, and the file is told.
    EXPECT_FALSE(s.closed_volumes()[4]);
    EXPECT_TRUE(has_warning(s, "material 4 \"bottle\": KHR_materials_volume on triangles that do not close"));
    // Every point of a quad: 1 - alpha through the curtain, 0.9 through the window.
    expect_near(s.transmittance_at(s.instances[1].first_triangle, glm::vec2(0.25f)), glm::vec3(0.6f));
    expect_near(s.transmittance_at(s.instances[2].first_triangle, glm::vec2(0.25f)), glm::vec3(0.9f));
    expect_near(s.transmittance_at(s.instances[3].first_triangle, glm::vec2(0.25f)), glm::vec3(0.0f));
    EXPECT_TRUE(
        has_warning(s, "material 0 \"leaves\": alphaMode MASK (cut-out): light passes where base colour alpha"));
    EXPECT_TRUE(has_warning(s, "material 1 \"curtain\": alphaMode BLEND: light passes in proportion"));
    EXPECT_TRUE(has_warning(s, "material 2 \"window\": KHR_materials_transmission: 0.9"));
    EXPECT_TRUE(has_warning(s, "KHR_materials_volume's absorption"));
    EXPECT_FALSE(has_warning(s, "\"wall\""));
    EXPECT_FALSE(has_warning(s, "not supported")) << "both extensions are read";
}

// Out-of-range see-through values are errors naming the material and the field.
TEST(GeneratedScenes, BadSeeThroughValuesAreErrorsNamingTheField) {
    const std::vector<std::pair<nlohmann::json, std::string>> cases = {
        {{{"alphaMode", "CLEAR"}}, "alphaMode \"CLEAR\" is not OPAQUE, MASK or BLEND"},
        {{{"alphaMode", "MASK"}, {"alphaCutoff", -0.5}}, "alphaCutoff"},
        {{{"extensions", {{"KHR_materials_transmission", {{"transmissionFactor", 1.5}}}}}}, "transmissionFactor"},
        {{{"extensions", {{"KHR_materials_transmission", {{"transmissionFactor", "all"}}}}}}, "transmissionFactor"},
        {{{"extensions",
           {{"KHR_materials_transmission", {{"transmissionFactor", 1.0}}},
            {"KHR_materials_volume", {{"attenuationDistance", 0.0}}}}}},
         "attenuationDistance"},
        {{{"extensions",
           {{"KHR_materials_transmission", {{"transmissionFactor", 1.0}}},
            {"KHR_materials_volume", {{"attenuationColor", {2.0, 0.5, 0.5}}}}}}},
         "attenuationColor"},
    };
    for (const auto& [material, message] : cases) {
        SCOPED_TRACE(material.dump());
        GltfWriter w;
        nlohmann::json m = material;
        m["name"] = "glass";
        w.add("materials", m);
        w.scene({w.add("nodes", {{"mesh", w.mesh(primitive(w.vec3(kQuad), w.scalars(kQuadIndices, test::kUnsignedShort),
                                                           {{"material", 0}}))}})});
        TempDir dir;
        try {
            load_written(w, dir);
            ADD_FAILURE() << "loaded";
        } catch (const SceneError& e) {
            EXPECT_NE(std::string(e.what()).find("material 0 \"glass\""), std::string::npos) << e.what();
            EXPECT_NE(std::string(e.what()).find(message), std::string::npos) << e.what();
        }
    }
}

TEST(GeneratedScenes, PrimitiveWithoutMaterialGetsAWhiteDefault) {
    GltfWriter w;
    w.add("materials", {{"pbrMetallicRoughness", {{"baseColorFactor", {0.5, 0.25, 0.125, 1.0}}}}});
    const int positions = w.vec3(kQuad);
    const int indices = w.scalars(kQuadIndices, test::kUnsignedShort);
    w.scene({w.add("nodes", {{"mesh", w.mesh(primitive(positions, indices, {{"material", 0}}))}}),
             w.add("nodes", {{"mesh", w.mesh(primitive(positions, indices))}})});
    TempDir dir;
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.materials.size(), 2u);
    EXPECT_EQ(s.materials[0].base_color, glm::vec4(0.5f, 0.25f, 0.125f, 1.0f));
    EXPECT_EQ(s.materials[1].base_color, glm::vec4(1.0f));
    EXPECT_EQ(s.triangle_material[0], 0u);
    EXPECT_EQ(s.triangle_material[2], 1u);
    EXPECT_TRUE(has_warning(s, "no light source"));
}

TEST(GeneratedScenes, SpotLightConeAndDirectionFromTheNode) {
    GltfWriter w;
    w.doc["extensionsUsed"] = {"KHR_lights_punctual"};
    w.doc["extensions"]["KHR_lights_punctual"]["lights"] = {
        {{"type", "spot"},
         {"color", {1.0, 0.5, 0.25}},
         {"intensity", 8.0},
         {"spot", {{"innerConeAngle", 0.2}, {"outerConeAngle", 0.6}}}},
        {{"type", "point"}, {"intensity", 2.0}, {"range", 10.0}},
    };
    // -90 degrees about X turns the light's -Z towards -Y.
    const double h = std::sqrt(0.5);
    const int spot = w.add("nodes", {{"translation", {1, 3, 2}},
                                     {"rotation", {-h, 0, 0, h}},
                                     {"extensions", {{"KHR_lights_punctual", {{"light", 0}}}}}});
    const int point =
        w.add("nodes", {{"translation", {0, 1, 0}}, {"extensions", {{"KHR_lights_punctual", {{"light", 1}}}}}});
    const int parent = w.add("nodes", {{"children", {point}}, {"translation", {5, 0, 0}}});
    w.scene({w.add("nodes", {{"mesh", w.mesh(primitive(w.vec3(kQuad)))}}), spot, parent});
    TempDir dir;
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.lights.size(), 2u);
    const PunctualLight& l = s.lights[0];
    EXPECT_EQ(l.type, PunctualLight::Type::Spot);
    expect_near(l.position, glm::vec3(1, 3, 2));
    expect_near(l.direction, glm::vec3(0, -1, 0));
    expect_near(l.intensity, glm::vec3(8, 4, 2));  // W/sr: colour x intensity, no 683
    EXPECT_NEAR(l.inner_cone, 0.2f, 1e-6f);
    EXPECT_NEAR(l.outer_cone, 0.6f, 1e-6f);
    EXPECT_EQ(s.lights[1].type, PunctualLight::Type::Point);
    expect_near(s.lights[1].position, glm::vec3(5, 1, 0));
    expect_near(s.lights[1].intensity, glm::vec3(2, 2, 2));
    EXPECT_FLOAT_EQ(s.lights[1].range, 10.0f);
    EXPECT_FALSE(has_warning(s, "no light"));
    const json summary = protocol::to_json(summarize(s));
    EXPECT_EQ(summary["punctual_lights"]["spot"], 1);
    EXPECT_EQ(summary["punctual_lights"]["point"], 1);
}

// Probes can be placed in the file: nodes whose extras hold
// {"lightfarm_probe": true} give their world positions (children of
// transformed parents included); other extras are ignored.
TEST(GeneratedScenes, NodesMarkedAsProbesGiveProbePoints) {
    TempDir dir;
    GltfWriter w;
    const int mesh = w.mesh(primitive(w.vec3(kQuad)));
    const int probe = w.add("nodes", {{"translation", {1, 2, 3}}, {"extras", {{"lightfarm_probe", true}}}});
    const int other = w.add("nodes", {{"translation", {9, 9, 9}}, {"extras", {{"lightfarm_probe", false}}}});
    w.add("nodes", {{"mesh", mesh}, {"translation", {0, 1, 0}}, {"children", {probe, other}}});
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.probe_points.size(), 1u);
    expect_near(s.probe_points[0], glm::vec3(1, 3, 3));
}

// Coordinates near float's limit are finite, so the accessor checks pass
// them, but no derived size survives them (fuzzing found two overflows in
// the atlas): a scene farther than LoadLimits::max_coordinate from the
// origin is refused, naming the distance.
TEST(GeneratedScenes, ASceneBeyondTheCoordinateLimitIsRefused) {
    TempDir dir;
    GltfWriter w;
    const int mesh = w.mesh(primitive(w.vec3({{0, 0, 0}, {1e30f, 0, 0}, {0, 0, 1e30f}})));
    w.add("nodes", {{"mesh", mesh}});
    try {
        load_scene(w.write(dir.path(), "far.gltf"));
        FAIL() << "loaded";
    } catch (const SceneError& e) {
        EXPECT_NE(std::string(e.what()).find("far.gltf: the scene reaches 1e+30 m"), std::string::npos) << e.what();
    }
    LoadLimits wide;
    wide.max_coordinate = 2e30f;
    EXPECT_NO_THROW(load_scene(w.write(dir.path(), "far.gltf"), wide));
}

// The upload check (`inspect`) reads image headers only: sizes and the texel
// budget are checked, no pixel is decoded, so a small file claiming a huge
// image costs nothing to look at. The same file still refuses an image over
// the size limit.
TEST(GeneratedScenes, HeadersOnlyLoadChecksSizesWithoutDecoding) {
    TempDir dir;
    const GltfWriter w = textured_quad({{"uri", std::string("data:image/png;base64,") + kGreyPng}});
    LoadLimits headers_only;
    headers_only.decode_images = false;
    const Scene s = load_scene(w.write(dir.path(), "scene.gltf"), headers_only);
    ASSERT_EQ(s.textures.size(), 1u);
    EXPECT_EQ(s.textures[0].width, 1);
    EXPECT_EQ(s.textures[0].height, 1);
    EXPECT_TRUE(s.textures[0].texels.empty());
    headers_only.max_texture_dim = 0;
    EXPECT_THROW(load_scene(w.write(dir.path(), "scene.gltf"), headers_only), SceneError);
}

TEST(GeneratedScenes, TexturesAreDecodedFromSrgb) {
    TempDir dir;
    const Scene s = load_written(textured_quad({{"uri", std::string("data:image/png;base64,") + kGreyPng}}), dir);
    ASSERT_EQ(s.textures.size(), 1u);  // one image behind both slots: decoded once
    ASSERT_EQ(s.textures[0].width, 1);
    const glm::vec4 texel = s.textures[0].fetch(0, 0);
    EXPECT_NEAR(texel.r, 0.2158605f, 1e-5f);       // sRGB 128/255 -> linear
    EXPECT_NEAR(texel.a, 128.0f / 255.0f, 1e-6f);  // alpha is linear
    EXPECT_EQ(s.materials[0].base_color_texture, 0);
    EXPECT_EQ(s.materials[0].emissive_texture, 0);
    EXPECT_NEAR(s.albedo_at(0, glm::vec2(0.3f, 0.3f)).g, 0.2158605f, 1e-5f);
    EXPECT_NEAR(s.emission_at(0, glm::vec2(0.3f, 0.3f)).b, 0.2158605f, 1e-5f);
}

TEST(GeneratedScenes, ExternalFilesInsideTheSceneDirectory) {
    TempDir dir;
    fs::create_directory(dir / "tex");
    const std::string png = test::base64_decode(kRedBluePng);
    test::write_text(dir / "tex" / "red blue.png", png);
    GltfWriter w = textured_quad({{"uri", "tex/red%20blue.png"}, {"name", "rb"}});
    const Scene s = load_scene(w.write(dir.path(), "external.gltf", "geometry.bin"));
    ASSERT_EQ(s.textures.size(), 1u);
    EXPECT_EQ(s.textures[0].width, 2);
    EXPECT_NEAR(s.textures[0].fetch(0, 0).r, 1.0f, 1e-6f);
    EXPECT_NEAR(s.textures[0].fetch(1, 0).b, 1.0f, 1e-6f);
    EXPECT_EQ(s.triangles.size(), 2u);
}

TEST(GeneratedScenes, GlbWithEmbeddedImage) {
    const std::string png = test::base64_decode(kGreyPng);
    GltfWriter w;
    const int view = w.view(png.data(), png.size());
    w = textured_quad({{"bufferView", view}, {"mimeType", "image/png"}}, std::move(w));
    TempDir dir;
    const Scene s = load_scene(w.write_glb(dir.path(), "embedded.glb"));
    ASSERT_EQ(s.textures.size(), 1u);
    EXPECT_NEAR(s.textures[0].fetch(0, 0).g, 0.2158605f, 1e-5f);
}

// ============================================================================
// Generated files the loader must refuse, or accept with a warning
// ============================================================================

TEST(GeneratedScenes, PointsAndLinesAreSkippedWithAWarning) {
    GltfWriter w = quad_file();
    w.doc["meshes"][0]["primitives"].push_back(primitive(0, 1, {{"mode", 1}}));   // LINES
    w.doc["meshes"][0]["primitives"].push_back(primitive(0, -1, {{"mode", 0}}));  // POINTS
    TempDir dir;
    const Scene s = load_written(w, dir);
    EXPECT_EQ(s.instances.size(), 1u);
    EXPECT_EQ(s.triangles.size(), 2u);
    EXPECT_TRUE(has_warning(s, "mesh 0 primitive 1: LINES skipped"));
    EXPECT_TRUE(has_warning(s, "mesh 0 primitive 2: POINTS skipped"));
}

// A mesh's lightmap scale comes from its node's extras, else its mesh's,
// else 1 (0: no lightmap); a value outside [0, 64] is refused naming the
// node or the mesh.
TEST(GeneratedScenes, TheLightmapScaleIsReadFromTheNodeElseTheMesh) {
    TempDir dir;
    const auto scale_with = [&](const nlohmann::json& node_extras, const nlohmann::json& mesh_extras) {
        GltfWriter w = quad_file();
        if (!node_extras.is_null()) w.doc["nodes"][0]["extras"] = node_extras;
        if (!mesh_extras.is_null()) w.doc["meshes"][0]["extras"] = mesh_extras;
        return w;
    };
    const auto scale_of = [&](const GltfWriter& w) { return load_written(w, dir).instances.at(0).lightmap_scale; };
    const nlohmann::json none;
    EXPECT_FLOAT_EQ(scale_of(scale_with(none, none)), 1.0f);
    EXPECT_FLOAT_EQ(scale_of(scale_with({{"lightfarm_lightmap_scale", 3}}, none)), 3.0f);
    EXPECT_FLOAT_EQ(scale_of(scale_with(none, {{"lightfarm_lightmap_scale", 0.25}})), 0.25f);
    EXPECT_FLOAT_EQ(scale_of(scale_with({{"lightfarm_lightmap_scale", 2}}, {{"lightfarm_lightmap_scale", 0.25}})), 2.0f)
        << "the node's wins";
    EXPECT_FLOAT_EQ(scale_of(scale_with({{"other", 2}}, none)), 1.0f) << "other extras are not a scale";
    EXPECT_FLOAT_EQ(scale_of(scale_with({{"lightfarm_lightmap_scale", 0}}, none)), 0.0f) << "no lightmap";
    const Scene left_out = load_written(scale_with(none, {{"lightfarm_lightmap_scale", 0}}), dir);
    EXPECT_FALSE(left_out.instances.at(0).has_lightmap());
    // inspect says it, as it says any scale but 1.
    EXPECT_EQ(protocol::to_json(summarize(left_out))["lightmap_scales"], json({{"0", 0.0}}));
    EXPECT_TRUE(contains(format_summary(left_out), "mesh 0 no lightmap (casts and bounces light)"))
        << format_summary(left_out);
    EXPECT_TRUE(contains(format_summary(load_written(scale_with({{"lightfarm_lightmap_scale", 3}}, none), dir)),
                         "lightmap scale: mesh 0 x3;"));
    EXPECT_TRUE(protocol::to_json(summarize(load_written(scale_with(none, none), dir)))["lightmap_scales"].empty());
    for (const nlohmann::json& bad :
         {nlohmann::json(-0.001), nlohmann::json(-1), nlohmann::json(64.5), nlohmann::json("big")}) {
        EXPECT_TRUE(
            contains(load_error(scale_with({{"lightfarm_lightmap_scale", bad}}, none).write(dir.path(), "n.gltf")),
                     "node 0: extras.lightfarm_lightmap_scale must be a number from 0 to 64"))
            << bad;
        EXPECT_TRUE(
            contains(load_error(scale_with(none, {{"lightfarm_lightmap_scale", bad}}).write(dir.path(), "m.gltf")),
                     "mesh 0: extras.lightfarm_lightmap_scale must be a number from 0 to 64"))
            << bad;
    }
}

TEST(GeneratedScenes, SceneChoice) {
    // Two scenes: "scene": 1 picks the second; without "scene", scene 0; without scenes, every root.
    GltfWriter w = quad_file();
    const int second = w.add("nodes", {{"mesh", 0}, {"translation", {0, 0, 7}}});
    w.doc["scenes"].push_back({{"nodes", {second}}});
    w.doc["scene"] = 1;
    TempDir dir;
    Scene s = load_written(w, dir, "one.gltf");
    ASSERT_EQ(s.instances.size(), 1u);
    EXPECT_EQ(s.instances[0].node, second);
    w.doc.erase("scene");
    s = load_written(w, dir, "two.gltf");
    ASSERT_EQ(s.instances.size(), 1u);
    EXPECT_EQ(s.instances[0].node, 0);
    w.doc.erase("scenes");
    s = load_written(w, dir, "three.gltf");
    EXPECT_EQ(s.instances.size(), 2u);
    w.doc["scene"] = 5;
    w.doc["scenes"] = {{{"nodes", {0}}}};
    EXPECT_TRUE(contains(load_error(w.write(dir.path(), "four.gltf")), "scene 5"));
}

TEST(GeneratedScenes, NodeWithTwoParentsIsRefused) {
    GltfWriter w = quad_file();
    w.add("nodes", {{"children", {0}}});
    w.add("nodes", {{"children", {0}}});
    w.doc["scenes"][0]["nodes"] = {1, 2};
    TempDir dir;
    const std::string message = load_error(w.write(dir.path(), "parents.gltf"));
    EXPECT_TRUE(contains(message, "parents.gltf: node 0: has two parents, node 1 and node 2")) << message;
}

TEST(GeneratedScenes, LongNodeChainIsNoRecursion) {
    // 100,000 nested nodes: walked with a stack of our own, not the call stack.
    GltfWriter w = quad_file();
    const int depth = 100000;
    for (int i = 1; i < depth; ++i) w.add("nodes", {{"children", {i - 1}}, {"translation", {0, 0, 0.001}}});
    w.doc["scenes"][0]["nodes"] = {depth - 1};
    TempDir dir;
    const Scene s = load_written(w, dir);
    ASSERT_EQ(s.instances.size(), 1u);
    EXPECT_NEAR(s.positions[0].z, 0.001f * (depth - 1), 1e-3f);
}

TEST(GeneratedScenes, UrisThatLeaveTheSceneAreRefused) {
    TempDir dir;
    fs::create_directory(dir / "scene");
    test::write_text(dir / "outside.bin", std::string(48, '\0'));
    fs::create_symlink(dir / "outside.bin", dir / "scene" / "link.bin");
    const std::map<std::string, std::string> uris = {
        {"%2Fetc%2Fpasswd", "absolute"},
        {"file:///etc/passwd", "scheme"},
        {"http://example.com/x.bin", "scheme"},
        {"sub/../../outside.bin", "leaves the scene directory"},
        {"link.bin", "symbolic link"},
        {"x.bin%zz", "%-escape"},
        {"x.bin#frag", "fragment"},
    };
    for (const auto& [uri, why] : uris) {
        SCOPED_TRACE(uri);
        GltfWriter w = quad_file();
        json doc = w.full();
        doc["buffers"][0]["uri"] = uri;
        test::write_text(dir / "scene" / "uri.gltf", doc.dump());
        const std::string message = load_error(dir / "scene" / "uri.gltf");
        EXPECT_TRUE(contains(message, "uri.gltf: buffer 0: uri")) << message;
        EXPECT_TRUE(contains(message, why)) << message;
    }
}

TEST(GeneratedScenes, SpecialFilesAreRefusedWithoutWaiting) {
    // A FIFO would block a plain open() until someone writes to it.
    TempDir dir;
    ASSERT_EQ(::mkfifo((dir / "fifo.gltf").c_str(), 0600), 0);
    ASSERT_EQ(::mkfifo((dir / "fifo.bin").c_str(), 0600), 0);
    std::string message = load_error(dir / "fifo.gltf");
    EXPECT_TRUE(contains(message, "fifo.gltf: is not a regular file")) << message;
    json doc = quad_file().full();
    doc["buffers"][0]["uri"] = "fifo.bin";
    test::write_text(dir / "uses_fifo.gltf", doc.dump());
    message = load_error(dir / "uses_fifo.gltf");
    EXPECT_TRUE(contains(message, "not a regular file")) << message;
}

TEST(GeneratedScenes, ImagesMissingUnusedOrUndecodable) {
    TempDir dir;
    // Used and missing: an error naming the image.
    std::string message =
        load_error(textured_quad({{"uri", "nope.png"}, {"name", "wall"}}).write(dir.path(), "a.gltf"));
    EXPECT_TRUE(contains(message, "a.gltf: image 0 \"wall\": uri \"nope.png\"")) << message;
    EXPECT_TRUE(contains(message, "not found")) << message;
    // Used and not an image.
    test::write_text(dir / "garbage.png", "this is not a PNG at all");
    message = load_error(textured_quad({{"uri", "garbage.png"}}).write(dir.path(), "b.gltf"));
    EXPECT_TRUE(contains(message, "b.gltf: image 0: not a decodable PNG or JPEG image")) << message;
    // Unused and missing: a warning only.
    GltfWriter w = quad_file();
    w.add("images", {{"uri", "nope.png"}});
    const Scene s = load_written(w, dir, "c.gltf");
    EXPECT_TRUE(has_warning(s, "image 0 is not used")) << s.warnings.front();
}

TEST(GeneratedScenes, LimitsAreEnforced) {
    TempDir dir;
    GltfWriter three = quad_file();  // the quad placed three times: 6 triangles
    three.doc["scenes"][0]["nodes"] = {0, three.add("nodes", {{"mesh", 0}}), three.add("nodes", {{"mesh", 0}})};
    const fs::path quad = three.write(dir.path(), "quad.gltf");
    LoadLimits limits;
    limits.max_triangles = 5;
    EXPECT_TRUE(contains(load_error(quad, limits), "6 triangles after node instancing, over the limit of 5"));
    limits.max_triangles = 6;
    EXPECT_NO_THROW(load_scene(quad, limits));

    // A strip makes a triangle per index byte: refused before it is assembled.
    GltfWriter strip;
    std::vector<uint8_t> cycle(1000);
    for (size_t i = 0; i < cycle.size(); ++i) cycle[i] = uint8_t(i % 3);
    const int positions = strip.vec3({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}});
    const int indices = strip.scalars(cycle, test::kUnsignedByte);
    strip.scene({strip.add("nodes", {{"mesh", strip.mesh(primitive(positions, indices, {{"mode", 5}}))}})});
    limits.max_triangles = 500;
    const std::string message = load_error(strip.write(dir.path(), "strip.gltf"), limits);
    EXPECT_TRUE(contains(message, "strip.gltf: mesh 0 primitive 0: brings the scene to 998 triangles")) << message;
    limits.max_triangles = 998;
    EXPECT_EQ(load_scene(dir / "strip.gltf", limits).triangle_count(), 998u);
    limits = {};
    limits.max_file_bytes = 100;
    EXPECT_TRUE(contains(load_error(quad, limits), "over the limit of 100 bytes"));

    const fs::path textured =
        textured_quad({{"uri", std::string("data:image/png;base64,") + kRedBluePng}}).write(dir.path(), "tex.gltf");
    limits = {};
    limits.max_texture_dim = 1;
    EXPECT_TRUE(contains(load_error(textured, limits), "image 0: dimensions 2x1 exceed the limit of 1"));
    limits = {};
    limits.max_total_texels = 1;
    EXPECT_TRUE(contains(load_error(textured, limits), "texture budget"));
}

TEST(GeneratedScenes, GlbBinChunkShorterThanItsBuffer) {
    GltfWriter w = quad_file();
    TempDir dir;
    ASSERT_NO_THROW(load_scene(w.write_glb(dir.path(), "fine.glb")));
    json doc = w.full({}, true);
    doc["buffers"][0]["byteLength"] = 4096;
    const std::string message = load_error(w.write_glb(dir.path(), "short.glb", doc));
    EXPECT_TRUE(contains(message, "short.glb: buffer 0: byteLength 4096 exceeds the GLB BIN chunk")) << message;
}

// ============================================================================
// Robustness: mutated files are loaded or refused, nothing else
// ============================================================================

// Loads `file`: a Scene or a SceneError are both fine; anything else is a bug.
void load_or_refuse(const fs::path& file, const std::string& what) {
    try {
        const Scene s = load_scene(file);
        expect_consistent(s);
    } catch (const SceneError& e) {
        const std::string message = e.what();
        EXPECT_EQ(message.find('\n'), std::string::npos) << what << ": " << message;
    } catch (const std::exception& e) {
        ADD_FAILURE() << what << ": " << typeid(e).name() << ": " << e.what();
    }
}

// One albedo per triangle (what the GPU's hit shading reads) is the
// texture's mean over the triangle, not one sample at its centroid: a
// two-texel stripe texture across a triangle, against a dense average.
TEST(SceneShading, TriangleAlbedoIsTheTexturesMeanOverTheTriangle) {
    Scene s;
    const uint32_t m = test::add_material(s, glm::vec3(1.0f));
    s.materials[m].base_color_texture = 0;
    Texture stripes;
    stripes.width = 2;
    stripes.height = 1;
    stripes.texels = {glm::vec4(0.9f), glm::vec4(0.1f)};
    s.textures.push_back(stripes);
    test::add_mesh(s, {{0, 0, 0}, {1, 0, 0}, {1, 0, 1}}, {{0, 1, 2}}, m);
    s.uv0 = {{0, 0}, {1, 0}, {1, 1}};
    double dense = 0.0;
    int n = 0;
    for (int i = 0; i < 400; ++i)
        for (int j = 0; i + j < 400; ++j, ++n)
            dense += s.albedo_at(0, glm::vec2((float(i) + 0.3f) / 400.0f, (float(j) + 0.3f) / 400.0f)).x;
    dense /= n;
    const float centroid = s.albedo_at(0, glm::vec2(1.0f / 3.0f)).x;
    EXPECT_NEAR(s.mean_albedo(0).x, dense, 0.02);
    EXPECT_GT(std::abs(centroid - dense), 0.05) << "the centroid sample was the old answer, and a wrong one";
    // Without a texture the mean is the base colour exactly.
    const uint32_t plain = test::add_material(s, glm::vec3(0.25f, 0.5f, 0.75f));
    s.triangle_material[0] = plain;
    EXPECT_EQ(s.mean_albedo(0), glm::vec3(0.25f, 0.5f, 0.75f));
}

TEST(Robustness, FeatureFileLoads) {
    TempDir dir;
    const Scene s = load_scene(feature_file().write_glb(dir.path(), "features.glb"));
    EXPECT_EQ(s.instances.size(), 4u);
    EXPECT_EQ(s.lights.size(), 1u);
    EXPECT_EQ(s.textures.size(), 1u);
    expect_consistent(s);
}

TEST(Robustness, MutatedJsonValues) {
    const GltfWriter w = feature_file();
    const json base = w.full({}, true);
    // Every number in the document is a place to put a hostile value.
    std::vector<json::json_pointer> numbers;
    const json flat = base.flatten();
    for (const auto& [path, value] : flat.items()) {
        if (value.is_number()) numbers.emplace_back(path);
    }
    const std::vector<json> hostile = {-1,
                                       0,
                                       1,
                                       2,
                                       3,
                                       5,
                                       6,
                                       7,
                                       13,
                                       255,
                                       65535,
                                       2147483647,
                                       4294967295ull,
                                       4294967296ull,
                                       18446744073709551615ull,
                                       -2147483648ll,
                                       0.5,
                                       1.5,
                                       -0.0,
                                       1e300,
                                       -1e300,
                                       9007199254740993ull,
                                       json("x"),
                                       json::array(),
                                       nullptr};
    std::mt19937 rng(20261122);
    TempDir dir;
    for (int iteration = 0; iteration < 1500; ++iteration) {
        json doc = base;
        const int changes = 1 + int(rng() % 3);
        std::string what;
        for (int c = 0; c < changes; ++c) {
            const json::json_pointer& at = numbers[rng() % numbers.size()];
            const json& value = hostile[rng() % hostile.size()];
            doc[at] = value;
            what += at.to_string() + "=" + value.dump() + " ";
        }
        // A new name each time: rewriting one file in place makes ext4 flush it on every close.
        const fs::path file = w.write_glb(dir.path(), "mutated" + std::to_string(iteration) + ".glb", doc);
        load_or_refuse(file, what);
        fs::remove(file);
    }
}

TEST(Robustness, MutatedAndTruncatedBytes) {
    TempDir dir;
    const fs::path original = feature_file().write_glb(dir.path(), "features.glb");
    std::ifstream in(original, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    std::mt19937 rng(7);
    for (int iteration = 0; iteration < 1500; ++iteration) {
        std::string mutated = bytes;
        const int flips = 1 + int(rng() % 4);
        for (int f = 0; f < flips; ++f) mutated[rng() % mutated.size()] = char(rng() % 256);
        const fs::path file = dir / ("mutated" + std::to_string(iteration) + ".glb");
        test::write_text(file, mutated);
        load_or_refuse(file, "byte mutation " + std::to_string(iteration));
        fs::remove(file);
    }
    for (size_t length = 0; length < bytes.size(); length += 1 + length / 64) {
        const fs::path file = dir / ("truncated" + std::to_string(length) + ".glb");
        test::write_text(file, bytes.substr(0, length));
        load_or_refuse(file, "truncated to " + std::to_string(length));
        fs::remove(file);
    }
}

}  // namespace
}  // namespace lf
