// JSON-level checks of a glTF document, before tinygltf parses it.
#include "scene/gltf_document.h"
#include "scene/gltf_document_checks.h"

#include <algorithm>
#include <array>
#include <climits>

namespace lf::gltf {

namespace {

using nlohmann::json;

constexpr std::array<std::string_view, 4> kImplementedExtensions = {
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_transmission",
    "KHR_materials_volume",
};

// Walks the whole document (depth already bounded) and refuses integers that
// tinygltf would silently truncate to int. The few size_t fields tinygltf
// reads as such are exempt and checked where they are used; "extras" is
// application data nobody reads.
void check_integer_ranges(const json& value, const std::string& path, const Errors& errors) {
    if (value.is_object()) {
        for (const auto& [key, child] : value.items()) {
            if (key == "extras") continue;
            if (key == "byteLength" || key == "byteOffset" || key == "count") continue;
            check_integer_ranges(child, path + "/" + key, errors);
        }
    } else if (value.is_array()) {
        for (size_t i = 0; i < value.size(); ++i)
            check_integer_ranges(value[i], path + "/" + std::to_string(i), errors);
    } else if (value.is_number_unsigned()) {
        if (value.get<uint64_t>() > uint64_t(INT_MAX))
            errors.fail(printable(path, 60), "integer " + value.dump() + " is out of range");
    } else if (value.is_number_integer()) {
        const int64_t v = value.get<int64_t>();
        if (v < INT_MIN || v > INT_MAX)
            errors.fail(printable(path, 60), "integer " + value.dump() + " is out of range");
    }
}

}  // namespace

bool is_implemented_extension(std::string_view name) {
    return std::find(kImplementedExtensions.begin(), kImplementedExtensions.end(), name) !=
           kImplementedExtensions.end();
}

// --- field helpers ----------------------------------------------------------------

const json* DocumentChecker::member(const json& object, const char* key) {
    const auto it = object.find(key);
    return it == object.end() ? nullptr : &*it;
}

const json& DocumentChecker::array(const char* key) const {
    static const json empty = json::array();
    const json* a = member(root_, key);
    if (a == nullptr) return empty;
    if (!a->is_array()) errors_.fail(key, "must be an array");
    return *a;
}

const json& DocumentChecker::object_at(const json& items, size_t index, std::string_view what) const {
    const json& o = items[index];
    if (!o.is_object()) errors_.fail(what, int64_t(index), "must be a JSON object");
    return o;
}

uint64_t DocumentChecker::unsigned_field(const json& object, const char* key, const std::string& where, bool required,
                                         uint64_t fallback) const {
    const json* v = member(object, key);
    if (v == nullptr) {
        if (required) errors_.fail(where + ": " + key + " is missing");
        return fallback;
    }
    if (!v->is_number_unsigned())
        errors_.fail(where + ": " + key + " " + printable(v->dump(), 30) + " is not a non-negative integer");
    return v->get<uint64_t>();
}

int64_t DocumentChecker::index_field(const json& object, const char* key, const std::string& where, const char* target,
                                     bool required) const {
    const json* v = member(object, key);
    if (v == nullptr) {
        if (required) errors_.fail(where + ": " + key + " is missing");
        return -1;
    }
    if (!v->is_number_unsigned())
        errors_.fail(where + ": " + key + " " + printable(v->dump(), 30) + " is not a valid index");
    const uint64_t index = v->get<uint64_t>();
    const size_t count = array(target).size();
    if (index >= count) {
        errors_.fail(where + ": " + key + " " + std::to_string(index) + " does not exist (the file has " +
                     std::to_string(count) + " " + target + ")");
    }
    return int64_t(index);
}

// --- the checks, in the order tinygltf would meet the objects ----------------------

void DocumentChecker::check_asset() const {
    const json* asset = member(root_, "asset");
    if (asset == nullptr || !asset->is_object()) errors_.fail("asset", "missing (not a glTF 2.0 file)");
    const json* version = member(*asset, "version");
    if (version == nullptr || !version->is_string()) errors_.fail("asset", "version is missing");
    const std::string v = version->get<std::string>();
    if (v.size() < 3 || v.compare(0, 2, "2.") != 0 ||
        !std::all_of(v.begin() + 2, v.end(), [](char c) { return c >= '0' && c <= '9'; })) {
        errors_.fail("asset", "version " + in_quotes(v, 20) + " is not supported (glTF 2.x required)");
    }
    if (const json* min = member(*asset, "minVersion")) {
        if (!min->is_string() || min->get<std::string>() != "2.0")
            errors_.fail("asset", "minVersion " + printable(min->dump(), 20) + " is newer than the supported 2.0");
    }
}

void DocumentChecker::check_extensions(std::vector<std::string>* warnings) const {
    for (const json& name : array("extensionsRequired")) {
        if (!name.is_string()) errors_.fail("extensionsRequired", "holds a value that is not a string");
        const std::string n = name.get<std::string>();
        if (!is_implemented_extension(n))
            errors_.fail("extension " + printable(n, 60) + " is required by the file but not supported");
    }
    for (const json& name : array("extensionsUsed")) {
        if (!name.is_string()) errors_.fail("extensionsUsed", "holds a value that is not a string");
        const std::string n = name.get<std::string>();
        if (!is_implemented_extension(n))
            warnings->push_back("extension " + printable(n, 60) + " is not supported and was ignored");
    }
}

void DocumentChecker::check_buffers(uint64_t bin_chunk_size, bool has_bin_chunk, SceneFiles& files) {
    const json& buffers = array("buffers");
    for (size_t i = 0; i < buffers.size(); ++i) {
        const json& buffer = object_at(buffers, i, "buffer");
        const std::string where = Errors::label("buffer", int64_t(i));
        const uint64_t length = unsigned_field(buffer, "byteLength", where, true, 0);
        if (length == 0) errors_.fail(where + ": byteLength is 0");
        if (length > limits_.max_file_bytes) {
            errors_.fail(where + ": byteLength " + std::to_string(length) + " exceeds the limit of " +
                         std::to_string(limits_.max_file_bytes) + " bytes");
        }

        const json* uri = member(buffer, "uri");
        if (uri == nullptr) {
            if (!binary_ || i != 0) errors_.fail(where + ": uri is missing (only a GLB's first buffer may omit it)");
            if (!has_bin_chunk) errors_.fail(where + ": refers to the GLB BIN chunk, but the file has none");
            if (length > bin_chunk_size) {
                errors_.fail(where + ": byteLength " + std::to_string(length) + " exceeds the GLB BIN chunk (" +
                             std::to_string(bin_chunk_size) + " bytes)");
            }
            continue;
        }
        if (!uri->is_string()) errors_.fail(where + ": uri is not a string");
        const std::string& text = uri->get_ref<const std::string&>();

        if (is_data_uri(text)) {
            DataUri data;
            std::string why = parse_data_uri(text, &data);
            if (why.empty() && data.media_type != "application/octet-stream" &&
                data.media_type != "application/gltf-buffer")
                why = "data: URI has media type " + in_quotes(data.media_type, 40) + ", not application/octet-stream";
            uint64_t size = 0;
            if (why.empty()) base64_decoded_size(data.payload, &size, &why);
            if (!why.empty()) errors_.fail(where + ": " + why);
            if (size != length) {
                errors_.fail(where + ": data: URI holds " + std::to_string(size) + " bytes, byteLength says " +
                             std::to_string(length));
            }
            continue;
        }

        std::string why;
        const fs::path path = resolve_scene_file(files.scene_dir(), text, &why);
        if (path.empty()) errors_.fail(where + ": uri " + in_quotes(text) + ": " + why);
        std::error_code ec;
        const uint64_t size = fs::file_size(path, ec);
        if (ec) errors_.fail(where + ": file " + in_quotes(text) + " cannot be examined");
        // tinygltf insists on the exact size; saying so here is clearer than its message.
        if (size != length) {
            errors_.fail(where + ": file " + in_quotes(text) + " has " + std::to_string(size) +
                         " bytes, byteLength says " + std::to_string(length));
        }
        plan_external_read(where, text, size, files);
        files.approve(text, path);
    }
}

void DocumentChecker::plan_external_read(const std::string& where, const std::string& uri, uint64_t size,
                                         const SceneFiles& files) {
    planned_bytes_ += size;
    if (planned_bytes_ > files.remaining()) {
        errors_.fail(where + ": file " + in_quotes(uri) + " (" + std::to_string(size) +
                     " bytes) brings the scene over its limit of " + std::to_string(limits_.max_file_bytes) + " bytes");
    }
}

void DocumentChecker::check_buffer_views() const {
    const json& views = array("bufferViews");
    for (size_t i = 0; i < views.size(); ++i) {
        const json& view = object_at(views, i, "bufferView");
        const std::string where = Errors::label("bufferView", int64_t(i));
        index_field(view, "buffer", where, "buffers", true);
        unsigned_field(view, "byteOffset", where, false, 0);
        if (unsigned_field(view, "byteLength", where, true, 0) == 0) errors_.fail(where + ": byteLength is 0");
        if (member(view, "byteStride") != nullptr) {
            const uint64_t stride = unsigned_field(view, "byteStride", where, false, 0);
            if (stride < 4 || stride > 252 || stride % 4 != 0)
                errors_.fail(where + ": byteStride " + std::to_string(stride) + " is not a multiple of 4 in [4, 252]");
        }
    }
}

void DocumentChecker::check_accessors() const {
    static constexpr std::array<int, 6> kComponentTypes = {5120, 5121, 5122, 5123, 5125, 5126};
    static constexpr std::array<std::string_view, 7> kTypes = {"SCALAR", "VEC2", "VEC3", "VEC4",
                                                               "MAT2",   "MAT3", "MAT4"};
    const json& accessors = array("accessors");
    for (size_t i = 0; i < accessors.size(); ++i) {
        const json& accessor = object_at(accessors, i, "accessor");
        const std::string where = Errors::label("accessor", int64_t(i));
        index_field(accessor, "bufferView", where, "bufferViews", false);
        unsigned_field(accessor, "byteOffset", where, false, 0);
        const uint64_t component = unsigned_field(accessor, "componentType", where, true, 0);
        if (std::find(kComponentTypes.begin(), kComponentTypes.end(), int64_t(component)) == kComponentTypes.end())
            errors_.fail(where + ": componentType " + std::to_string(component) + " is not a glTF component type");
        if (unsigned_field(accessor, "count", where, true, 0) == 0) errors_.fail(where + ": count is 0");
        const json* type = member(accessor, "type");
        if (type == nullptr || !type->is_string()) errors_.fail(where + ": type is missing");
        if (std::find(kTypes.begin(), kTypes.end(), type->get<std::string>()) == kTypes.end())
            errors_.fail(where + ": type " + in_quotes(type->get<std::string>(), 20) + " is not a glTF accessor type");
        if (const json* normalized = member(accessor, "normalized"); normalized && !normalized->is_boolean())
            errors_.fail(where + ": normalized is not a boolean");
        if (const json* sparse = member(accessor, "sparse")) check_sparse(*sparse, where);
    }
}

void DocumentChecker::check_sparse(const json& sparse, const std::string& accessor) const {
    const std::string where = accessor + " sparse";
    if (!sparse.is_object()) errors_.fail(where + ": must be a JSON object");
    // tinygltf keeps these as int.
    const uint64_t count = unsigned_field(sparse, "count", where, true, 0);
    if (count == 0 || count > uint64_t(INT_MAX))
        errors_.fail(where + ": count " + std::to_string(count) + " is out of range");
    for (const char* part : {"indices", "values"}) {
        const json* p = member(sparse, part);
        if (p == nullptr || !p->is_object()) errors_.fail(where + ": " + part + " is missing");
        const std::string part_where = where + " " + part;
        index_field(*p, "bufferView", part_where, "bufferViews", true);
        if (unsigned_field(*p, "byteOffset", part_where, false, 0) > uint64_t(INT_MAX))
            errors_.fail(part_where + ": byteOffset is out of range");
    }
    const uint64_t component = unsigned_field(sparse["indices"], "componentType", where + " indices", true, 0);
    if (component != 5121 && component != 5123 && component != 5125)
        errors_.fail(where + " indices: componentType " + std::to_string(component) +
                     " is not an unsigned integer type");
}

void DocumentChecker::check_images(SceneFiles& files, std::vector<std::string>* warnings) {
    const json& images = array("images");
    for (size_t i = 0; i < images.size(); ++i) {
        const json& image = object_at(images, i, "image");
        std::string name;
        if (const json* n = member(image, "name"); n && n->is_string()) name = n->get<std::string>();
        const std::string where = Errors::label("image", int64_t(i), name);
        const json* uri = member(image, "uri");
        const bool has_view = member(image, "bufferView") != nullptr;
        if ((uri != nullptr) == has_view) errors_.fail(where + ": needs exactly one of uri and bufferView");
        if (has_view) {
            index_field(image, "bufferView", where, "bufferViews", true);
            continue;
        }
        if (!uri->is_string()) errors_.fail(where + ": uri is not a string");
        const std::string& text = uri->get_ref<const std::string&>();

        if (is_data_uri(text)) {
            DataUri data;
            std::string why = parse_data_uri(text, &data);
            // tinygltf decodes exactly these two media types (and PNG/JPEG are glTF's image formats).
            if (why.empty() && data.media_type != "image/png" && data.media_type != "image/jpeg")
                why = "data: URI has media type " + in_quotes(data.media_type, 40) + ", not image/png or image/jpeg";
            uint64_t size = 0;
            if (why.empty()) base64_decoded_size(data.payload, &size, &why);
            if (!why.empty()) errors_.fail(where + ": " + why);
            continue;
        }

        std::string why;
        const fs::path path = resolve_scene_file(files.scene_dir(), text, &why);
        if (path.empty()) {
            // A URI reaching outside the scene is hostile whether or not the image is
            // used; a merely missing file matters only if a kept material needs it.
            const bool missing = why.find("not found") != std::string::npos;
            if (!missing || used_images_[i]) errors_.fail(where + ": uri " + in_quotes(text) + ": " + why);
            warnings->push_back(where + " is not used and its file is missing: " + why);
            continue;
        }
        std::error_code ec;
        const uint64_t size = fs::file_size(path, ec);
        if (ec) errors_.fail(where + ": file " + in_quotes(text) + " cannot be examined");
        plan_external_read(where, text, size, files);
        files.approve(text, path);
    }
}

void DocumentChecker::find_used_images() {
    used_images_.assign(array("images").size(), false);
    const json& textures = array("textures");
    auto mark = [&](const json* info) {
        if (info == nullptr || !info->is_object()) return;
        const json* index = member(*info, "index");
        if (index == nullptr || !index->is_number_unsigned() || index->get<uint64_t>() >= textures.size()) return;
        const json& texture = textures[index->get<size_t>()];
        if (!texture.is_object()) return;
        const json* source = member(texture, "source");
        if (source == nullptr || !source->is_number_unsigned() || source->get<uint64_t>() >= used_images_.size())
            return;
        used_images_[source->get<size_t>()] = true;
    };
    for (const json& material : array("materials")) {
        if (!material.is_object()) continue;
        if (const json* pbr = member(material, "pbrMetallicRoughness"); pbr && pbr->is_object())
            mark(member(*pbr, "baseColorTexture"));
        mark(member(material, "emissiveTexture"));
    }
}

void DocumentChecker::check(uint64_t bin_chunk_size, bool has_bin_chunk, SceneFiles& files,
                            std::vector<std::string>* warnings) {
    if (!root_.is_object()) errors_.fail("the JSON document is not an object");
    check_asset();
    check_extensions(warnings);
    check_integer_ranges(root_, "", errors_);
    find_used_images();
    check_buffers(bin_chunk_size, has_bin_chunk, files);
    check_buffer_views();
    check_accessors();
    check_images(files, warnings);
}

}  // namespace lf::gltf
