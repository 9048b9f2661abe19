// Small glTF files written by tests: a JSON document plus one binary buffer,
// saved as .gltf (buffer as a base64 data: URI, or as an external .bin) or .glb.
#pragma once

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>

#include <stdlib.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <utility>
#include <string>
#include <vector>

namespace lf::test {

namespace fs = std::filesystem;

// A fresh directory under /tmp, removed with everything in it.
class TempDir {
public:
    TempDir() {
        std::string pattern = (fs::temp_directory_path() / "lightfarm-test-XXXXXX").string();
        if (::mkdtemp(pattern.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
        path_ = pattern;
    }
    ~TempDir() {
        std::error_code ec;
        fs::remove_all(path_, ec);
    }
    TempDir(const TempDir&) = delete;
    TempDir& operator=(const TempDir&) = delete;
    const fs::path& path() const { return path_; }
    fs::path operator/(const std::string& name) const { return path_ / name; }

private:
    fs::path path_;
};

inline std::string base64(const std::vector<uint8_t>& data) {
    static const char* table = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    std::string out;
    for (size_t i = 0; i < data.size(); i += 3) {
        const uint32_t b0 = data[i];
        const uint32_t b1 = i + 1 < data.size() ? data[i + 1] : 0;
        const uint32_t b2 = i + 2 < data.size() ? data[i + 2] : 0;
        const uint32_t v = (b0 << 16) | (b1 << 8) | b2;
        out += table[(v >> 18) & 63];
        out += table[(v >> 12) & 63];
        out += i + 1 < data.size() ? table[(v >> 6) & 63] : '=';
        out += i + 2 < data.size() ? table[v & 63] : '=';
    }
    return out;
}

inline std::string base64_decode(const std::string& text) {
    auto value = [](char c) -> uint32_t {
        if (c >= 'A' && c <= 'Z') return uint32_t(c - 'A');
        if (c >= 'a' && c <= 'z') return uint32_t(c - 'a' + 26);
        if (c >= '0' && c <= '9') return uint32_t(c - '0' + 52);
        return c == '+' ? 62u : 63u;
    };
    std::string out;
    for (size_t i = 0; i + 3 < text.size(); i += 4) {
        const uint32_t v = value(text[i]) << 18 | value(text[i + 1]) << 12 |
                           (text[i + 2] == '=' ? 0 : value(text[i + 2]) << 6) |
                           (text[i + 3] == '=' ? 0 : value(text[i + 3]));
        out += char(v >> 16);
        if (text[i + 2] != '=') out += char((v >> 8) & 255);
        if (text[i + 3] != '=') out += char(v & 255);
    }
    return out;
}

inline void write_bytes(const fs::path& path, const void* data, size_t size) {
    std::ofstream out(path, std::ios::binary);
    out.write(static_cast<const char*>(data), std::streamsize(size));
    if (!out) throw std::runtime_error("cannot write " + path.string());
}

inline void write_text(const fs::path& path, const std::string& text) { write_bytes(path, text.data(), text.size()); }

enum ComponentType : int {
    kByte = 5120,
    kUnsignedByte = 5121,
    kShort = 5122,
    kUnsignedShort = 5123,
    kUnsignedInt = 5125,
    kFloat = 5126,
};

class GltfWriter {
public:
    // Everything except buffers, bufferViews and accessors; tests fill in
    // nodes, meshes, materials, extensions ... directly.
    nlohmann::json doc = {{"asset", {{"version", "2.0"}}}};

    // Appends bytes to the buffer (4-byte aligned) as a new bufferView.
    int view(const void* data, size_t size, int stride = 0) {
        while (bin_.size() % 4 != 0) bin_.push_back(0);
        nlohmann::json v = {{"buffer", 0}, {"byteOffset", bin_.size()}, {"byteLength", size}};
        if (stride != 0) v["byteStride"] = stride;
        const auto* p = static_cast<const uint8_t*>(data);
        bin_.insert(bin_.end(), p, p + size);
        views_.push_back(v);
        return int(views_.size() - 1);
    }

    int accessor(int view, int component_type, size_t count, const char* type, bool normalized = false,
                 size_t byte_offset = 0) {
        nlohmann::json a = {{"componentType", component_type}, {"count", count}, {"type", type}};
        if (view >= 0) a["bufferView"] = view;
        if (byte_offset != 0) a["byteOffset"] = byte_offset;
        if (normalized) a["normalized"] = true;
        accessors_.push_back(a);
        return int(accessors_.size() - 1);
    }
    nlohmann::json& accessor_json(int index) { return accessors_[size_t(index)]; }

    int vec3(const std::vector<glm::vec3>& v) {
        const int a = accessor(view(v.data(), v.size() * sizeof(glm::vec3)), kFloat, v.size(), "VEC3");
        glm::vec3 lo(1e30f), hi(-1e30f);
        for (const glm::vec3& p : v) lo = glm::min(lo, p), hi = glm::max(hi, p);
        accessors_[size_t(a)]["min"] = {lo.x, lo.y, lo.z};
        accessors_[size_t(a)]["max"] = {hi.x, hi.y, hi.z};
        return a;
    }
    int vec2(const std::vector<glm::vec2>& v) {
        return accessor(view(v.data(), v.size() * sizeof(glm::vec2)), kFloat, v.size(), "VEC2");
    }
    template <typename T>
    int scalars(const std::vector<T>& v, int component_type, bool normalized = false, const char* type = "SCALAR") {
        const size_t per_element = std::string(type) == "VEC2" ? 2 : 1;
        return accessor(view(v.data(), v.size() * sizeof(T)), component_type, v.size() / per_element, type, normalized);
    }

    int add(const char* array, nlohmann::json item) {
        doc[array].push_back(std::move(item));
        return int(doc[array].size() - 1);
    }
    // A mesh of one primitive.
    int mesh(nlohmann::json primitive) { return add("meshes", {{"primitives", {std::move(primitive)}}}); }
    void scene(const std::vector<int>& roots) {
        doc["scenes"] = {{{"nodes", roots}}};
        doc["scene"] = 0;
    }

    // The document with the buffer as a data: URI (or as `bin_uri`, written by write()).
    nlohmann::json full(const std::string& bin_uri = {}, bool glb = false) const {
        nlohmann::json d = doc;
        if (!bin_.empty()) {
            nlohmann::json buffer = {{"byteLength", bin_.size()}};
            if (!glb)
                buffer["uri"] = bin_uri.empty() ? "data:application/octet-stream;base64," + base64(bin_) : bin_uri;
            d["buffers"] = nlohmann::json::array({buffer});  // not {buffer}: clang reads that as a copy
            d["bufferViews"] = views_;
            d["accessors"] = accessors_;
        }
        return d;
    }

    // Writes `name` (.gltf) into dir; with bin_name, the buffer goes to that file beside it.
    fs::path write(const fs::path& dir, const std::string& name, const std::string& bin_name = {}) const {
        if (!bin_name.empty()) write_bytes(dir / bin_name, bin_.data(), bin_.size());
        write_text(dir / name, full(bin_name).dump());
        return dir / name;
    }

    // Writes a GLB: JSON chunk and BIN chunk, both padded to 4 bytes; `document`
    // replaces the JSON that full() would give (to write a GLB that lies).
    fs::path write_glb(const fs::path& dir, const std::string& name, const nlohmann::json& document = nullptr) const {
        std::string json = (document.is_null() ? full({}, true) : document).dump();
        while (json.size() % 4 != 0) json += ' ';
        std::vector<uint8_t> bin = bin_;
        while (bin.size() % 4 != 0) bin.push_back(0);
        std::vector<uint8_t> out;
        auto u32 = [&](uint32_t v) {
            for (int i = 0; i < 4; ++i) out.push_back(uint8_t(v >> (8 * i)));
        };
        const uint32_t total = uint32_t(12 + 8 + json.size() + (bin.empty() ? 0 : 8 + bin.size()));
        u32(0x46546C67);
        u32(2);
        u32(total);
        u32(uint32_t(json.size()));
        u32(0x4E4F534A);
        out.insert(out.end(), json.begin(), json.end());
        if (!bin.empty()) {
            u32(uint32_t(bin.size()));
            u32(0x004E4942);
            out.insert(out.end(), bin.begin(), bin.end());
        }
        write_bytes(dir / name, out.data(), out.size());
        return dir / name;
    }

private:
    std::vector<uint8_t> bin_;
    nlohmann::json views_ = nlohmann::json::array();
    nlohmann::json accessors_ = nlohmann::json::array();
};

// --- sample files ---------------------------------------------------------------

// A unit quad in the XY plane facing +Z: counter-clockwise seen from +Z.
inline const std::vector<glm::vec3> kQuad = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
inline const std::vector<uint16_t> kQuadIndices = {0, 1, 2, 0, 2, 3};

inline nlohmann::json primitive(int position, int indices = -1, nlohmann::json extra = nlohmann::json::object()) {
    nlohmann::json p = {{"attributes", {{"POSITION", position}}}};
    if (indices >= 0) p["indices"] = indices;
    for (auto& [k, v] : extra.items()) p[k] = v;
    return p;
}

// A file with one quad, for variations.
inline GltfWriter quad_file() {
    GltfWriter w;
    const int positions = w.vec3(kQuad);
    const int indices = w.scalars(kQuadIndices, kUnsignedShort);
    w.scene({w.add("nodes", {{"mesh", w.mesh(primitive(positions, indices))}})});
    return w;
}

// 1x1 RGBA PNG, every channel 128; and 2x1 RGBA: red, blue.
inline const char* kGreyPng =
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAAC0lEQVR4nGNoAAIABQUCAaxTIjoAAAAASUVORK5CYII=";
inline const char* kRedBluePng =
    "iVBORw0KGgoAAAANSUhEUgAAAAIAAAABCAYAAAD0In+KAAAADklEQVR4nGP4z8AAQv8BD/kD/YURmXYAAAAASUVORK5CYII=";

// A quad whose material has base colour and emissive textures from images.
inline GltfWriter textured_quad(const nlohmann::json& image, GltfWriter w = GltfWriter()) {
    w.add("images", image);
    w.add("textures", {{"source", 0}});
    w.add("materials", {{"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}}},
                        {"emissiveFactor", {1.0, 1.0, 1.0}},
                        {"emissiveTexture", {{"index", 0}}}});
    const std::vector<glm::vec2> uv = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
    w.scene({w.add("nodes", {{"mesh", w.mesh({{"attributes", {{"POSITION", w.vec3(kQuad)}, {"TEXCOORD_0", w.vec2(uv)}}},
                                              {"indices", w.scalars(kQuadIndices, kUnsignedShort)},
                                              {"material", 0}})}})});
    return w;
}

// A small file that uses most of what the loader reads: indexed and strip
// primitives, normals, normalized UVs, a sparse accessor, an embedded PNG
// texture, a node hierarchy with TRS and matrix, a spot light.
inline GltfWriter feature_file() {
    const std::string png = base64_decode(kRedBluePng);
    GltfWriter w;
    const int image_view = w.view(png.data(), png.size());
    w = textured_quad({{"bufferView", image_view}, {"mimeType", "image/png"}}, std::move(w));
    const int positions = w.doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"];
    const std::vector<uint8_t> sparse_index = {1};
    const std::vector<glm::vec3> sparse_value = {{2, 0, 0}};
    const int iv = w.view(sparse_index.data(), 1);
    const int vv = w.view(sparse_value.data(), 12);
    w.accessor_json(positions)["sparse"] = {{"count", 1},
                                            {"indices", {{"bufferView", iv}, {"componentType", kUnsignedByte}}},
                                            {"values", {{"bufferView", vv}}}};
    const std::vector<uint16_t> uv = {0, 0, 65535, 0, 65535, 65535, 0, 65535};
    const std::vector<uint8_t> strip = {1, 0, 2, 3};
    w.doc["meshes"][0]["primitives"].push_back({{"attributes",
                                                 {{"POSITION", positions},
                                                  {"NORMAL", w.vec3(std::vector<glm::vec3>(4, glm::vec3(0, 0, 1)))},
                                                  {"TEXCOORD_1", w.scalars(uv, kUnsignedShort, true, "VEC2")}}},
                                                {"indices", w.scalars(strip, kUnsignedByte)},
                                                {"mode", 5}});
    w.doc["extensionsUsed"] = {"KHR_lights_punctual"};
    w.doc["extensions"]["KHR_lights_punctual"]["lights"] = {
        {{"type", "spot"}, {"intensity", 3.0}, {"spot", nlohmann::json::object()}}};
    const int light =
        w.add("nodes", {{"extensions", {{"KHR_lights_punctual", {{"light", 0}}}}}, {"rotation", {0, 0, 0, 1}}});
    const int child = w.add("nodes", {{"mesh", 0}, {"matrix", {-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 1, 2, 3, 1}}});
    const int root = w.add("nodes", {{"children", {child, light}}, {"scale", {2, 2, 2}}});
    w.doc["scenes"][0]["nodes"].push_back(root);
    return w;
}

}  // namespace lf::test
