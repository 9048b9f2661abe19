// Reading a .gltf/.glb file: the GLB container, the JSON's nesting, then the
// JSON-level checks (gltf_document.cpp).
#include "scene/gltf_document.h"
#include "scene/gltf_document_checks.h"
#include "scene/glb.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <limits>

namespace lf::gltf {

namespace {

// Deeper JSON than any glTF needs; tinygltf converts "extras" recursively.
constexpr int kMaxJsonDepth = 64;

bool has_glb_extension(const fs::path& file) {
    std::string ext = file.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    return ext == ".glb";
}

struct BinChunk {
    bool present = false;
    uint64_t size = 0;
};

// Checks the GLB header and chunks strictly enough that tinygltf's own GLB
// reader (which reads the BIN chunk 8 bytes past the length it checks) only
// ever sees a well-formed container. Sets the JSON range of `doc`.
BinChunk split_glb(Document& doc, const Errors& errors) {
    const std::vector<unsigned char>& b = doc.bytes;
    const uint64_t size = b.size();
    if (size < 12) errors.fail("GLB header", "file is only " + std::to_string(size) + " bytes");
    if (glb::read_u32(b.data(), 0) != glb::kMagic) errors.fail("GLB header", "magic is not \"glTF\"");
    const uint32_t version = glb::read_u32(b.data(), 4);
    if (version != 2)
        errors.fail("GLB header", "version " + std::to_string(version) + " is not supported (2 required)");
    const uint32_t length = glb::read_u32(b.data(), 8);
    if (length != size) {
        errors.fail("GLB header", "length says " + std::to_string(length) + " bytes, the file has " +
                                      std::to_string(size) + (length > size ? " (truncated)" : ""));
    }
    if (size > std::numeric_limits<uint32_t>::max()) errors.fail("GLB header", "file is 4 GiB or larger");

    if (size < 20) errors.fail("GLB chunk 0", "header is truncated");
    const uint64_t json_length = glb::read_u32(b.data(), 12);
    if (glb::read_u32(b.data(), 16) != glb::kChunkJson) errors.fail("GLB chunk 0", "is not the JSON chunk");
    if (json_length == 0 || 20 + json_length > size) {
        errors.fail("GLB chunk 0", "length " + std::to_string(json_length) + " exceeds the " +
                                       std::to_string(size - 20) + " bytes after its header");
    }
    doc.json_offset = 20;
    doc.json_size = size_t(json_length);

    BinChunk bin;
    const uint64_t bin_header = 20 + json_length;
    const uint64_t rest = size - bin_header;
    if (rest == 0) return bin;
    if (rest < 12) errors.fail("GLB chunk 1", "truncated (" + std::to_string(rest) + " bytes)");
    const uint64_t bin_length = glb::read_u32(b.data(), size_t(bin_header));
    if (glb::read_u32(b.data(), size_t(bin_header) + 4) != glb::kChunkBin)
        errors.fail("GLB chunk 1", "is not the BIN chunk");
    if (bin_length < 4 || bin_length % 4 != 0)
        errors.fail("GLB chunk 1", "length " + std::to_string(bin_length) + " is not a positive multiple of 4");
    if (bin_length > rest - 8) {
        errors.fail("GLB chunk 1", "length " + std::to_string(bin_length) + " exceeds the " + std::to_string(rest - 8) +
                                       " bytes after its header");
    }
    bin.present = true;
    bin.size = bin_length;
    return bin;
}

// The deepest nesting of arrays and objects, by a byte scan that knows strings.
int json_depth(std::string_view text) {
    int depth = 0, deepest = 0;
    bool in_string = false, escaped = false;
    for (char c : text) {
        if (in_string) {
            if (escaped) escaped = false;
            else if (c == '\\') escaped = true;
            else if (c == '"') in_string = false;
        } else if (c == '"') {
            in_string = true;
        } else if (c == '[' || c == '{') {
            deepest = std::max(deepest, ++depth);
        } else if (c == ']' || c == '}') {
            --depth;
        }
    }
    return deepest;
}

// nlohmann's messages start with "[json.exception.parse_error.101] ".
std::string without_exception_tag(const std::string& message) {
    const size_t end = message.find("] ");
    return message.rfind("[json.exception.", 0) == 0 && end != std::string::npos ? message.substr(end + 2) : message;
}

}  // namespace

Document read_document(const fs::path& file, const LoadLimits& limits, const Errors& errors, SceneFiles& files) {
    Document doc;
    doc.bytes = read_file_limited(file, files.remaining(), errors, "");
    files.charge(doc.bytes);
    if (doc.bytes.empty()) errors.fail("file is empty (0 bytes), not a glTF or GLB file");

    const bool glb_magic = doc.bytes.size() >= 4 && glb::read_u32(doc.bytes.data(), 0) == glb::kMagic;
    doc.binary = glb_magic || has_glb_extension(file);
    BinChunk bin;
    if (doc.binary) {
        bin = split_glb(doc, errors);
    } else {
        doc.json_offset = 0;
        doc.json_size = doc.bytes.size();
    }
    // tinygltf takes the JSON length as unsigned int and refuses fewer than 4 bytes.
    if (doc.json_size > std::numeric_limits<uint32_t>::max()) errors.fail("JSON is 4 GiB or larger");

    const std::string_view text(reinterpret_cast<const char*>(doc.bytes.data()) + doc.json_offset, doc.json_size);
    if (json_depth(text) > kMaxJsonDepth)
        errors.fail("JSON nests deeper than " + std::to_string(kMaxJsonDepth) + " levels");
    nlohmann::json root;
    try {
        root = nlohmann::json::parse(text.begin(), text.end());
    } catch (const nlohmann::json::exception& e) {
        errors.fail("not valid JSON: " + without_exception_tag(e.what()));
    }
    if (doc.json_size < 4) errors.fail("JSON is too short to be a glTF document");

    DocumentChecker checker(root, doc.binary, limits, errors);
    checker.check(bin.size, bin.present, files, &doc.warnings);
    doc.used_images = checker.used_images();
    return doc;
}

}  // namespace lf::gltf
