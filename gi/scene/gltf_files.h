// Files and URIs of a glTF scene (internal to gi/scene).
//
// A glTF file names other files (buffers, images) by URI. The loader resolves
// such a URI only to a regular file inside the scene's own directory: no
// scheme other than data:, no absolute path, no `..` leaving the directory,
// no symlink leading out of it, and no expansion of any kind (tinygltf's own
// ExpandFilePath runs wordexp, i.e. a shell-like expansion of `$(...)`).
//
// tinygltf still does the reading, through SceneFiles::callbacks(). Those
// callbacks serve only the files the loader approved beforehand, each under
// the exact path string tinygltf will ask for, so nothing tinygltf computes
// on its own can reach another file.
#pragma once

#include "scene/gltf_errors.h"
#include "util/hash.h"

#include <tiny_gltf.h>

#include <cstdint>
#include <filesystem>
#include <map>
#include <string>
#include <string_view>
#include <vector>

namespace lf::gltf {

namespace fs = std::filesystem;

// Reads a whole regular file. Its size is checked against max_bytes from the
// open descriptor before anything is read (so a huge or growing file is never
// buffered). `what` names the file in the error ("file", "buffer 0 file ...").
std::vector<unsigned char> read_file_limited(const fs::path& path, uint64_t max_bytes, const Errors& errors,
                                             const std::string& what);

// --- data: URIs ---------------------------------------------------------------

bool is_data_uri(std::string_view uri);

struct DataUri {
    std::string media_type;    // e.g. "application/octet-stream", lower case
    std::string_view payload;  // the base64 text
};

// Splits "data:<media type>;base64,<payload>". Returns an empty string on
// success, else what is wrong (only base64 data: URIs are glTF's).
std::string parse_data_uri(std::string_view uri, DataUri* out);

// Strict base64 (RFC 4648 alphabet, '=' padding only at the end, length a
// multiple of 4): the decoded size, or an error text in *why.
bool base64_decoded_size(std::string_view payload, uint64_t* size, std::string* why);

// --- relative URIs --------------------------------------------------------------

// Percent-decodes and resolves a relative URI reference against scene_dir
// (canonical). Returns the canonical path of an existing regular file, or an
// empty path with the reason in *why ("is absolute", "leaves the scene
// directory", "not found", ...).
fs::path resolve_scene_file(const fs::path& scene_dir, std::string_view uri, std::string* why);

// The files tinygltf may read, and the byte budget they share.
class SceneFiles {
public:
    SceneFiles(fs::path scene_dir, uint64_t byte_budget);

    // What to pass tinygltf as base_dir.
    const std::string& base_dir() const { return base_dir_; }
    const fs::path& scene_dir() const { return scene_dir_; }

    // Allows tinygltf to read `resolved` when it asks for the file of `uri`.
    void approve(std::string_view uri, const fs::path& resolved);

    // Bytes the budget still allows; the scene file itself is charged by the caller.
    uint64_t remaining() const { return budget_; }
    // Charges a file's bytes to the budget and adds them to the content hash.
    void charge(const std::vector<unsigned char>& bytes) {
        budget_ -= std::min<uint64_t>(budget_, bytes.size());
        content_hash_ = hash_bytes(bytes.data(), bytes.size(), content_hash_ * 31 + bytes.size());
    }
    // A hash of every byte read so far, file by file (Scene::content_hash).
    uint64_t content_hash() const { return content_hash_; }

    // Callbacks for tinygltf::TinyGLTF::SetFsCallbacks; `this` must outlive the load.
    tinygltf::FsCallbacks callbacks();

private:
    static bool file_exists(const std::string& path, void* self);
    static std::string expand_file_path(const std::string& path, void* self);
    static bool read_whole_file(std::vector<unsigned char>* out, std::string* err, const std::string& path, void* self);
    static bool write_whole_file(std::string* err, const std::string& path, const std::vector<unsigned char>& data,
                                 void* self);

    fs::path scene_dir_;
    std::string base_dir_;
    uint64_t budget_;
    uint64_t content_hash_ = kHashSeed;
    // tinygltf's path string (base_dir joined with its own decoding of the URI) -> approved file.
    std::map<std::string, fs::path> approved_;
};

}  // namespace lf::gltf
