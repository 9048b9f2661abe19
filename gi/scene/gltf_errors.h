// Error messages of the glTF loader (internal to gi/scene).
//
// Every refusal is one line, "<file name>: <object> <index>: <what>", so a
// user (or the server's upload answer) sees exactly which part of the file is
// wrong. Text that comes from the file (URIs, names, tinygltf's messages) is
// passed through printable() first: a hostile file must not be able to put
// newlines, control characters or megabytes of base64 into a message.
#pragma once

#include "scene/gltf_loader.h"

#include <cstdint>
#include <string>
#include <string_view>

namespace lf::gltf {

// File text made safe for a one-line message: control characters become '?',
// and anything longer than max_chars is cut with "...".
std::string printable(std::string_view text, size_t max_chars = 80);

// printable() in double quotes, for URIs and names.
std::string in_quotes(std::string_view text, size_t max_chars = 80);

// Builds the messages for one file; `file_name` is the file's name without its
// directory (the directory is the caller's, not the file's, business).
class Errors {
public:
    explicit Errors(std::string file_name) : file_(std::move(file_name)) {}

    const std::string& file_name() const { return file_; }

    // "<file>: <what>" for the file as a whole (container, JSON, limits).
    [[noreturn]] void fail(const std::string& what) const;
    // "<file>: <object> <index>: <what>", e.g. object "accessor", index 12.
    [[noreturn]] void fail(std::string_view object, int64_t index, const std::string& what) const;
    // "<file>: <object>: <what>" for objects without an index ("asset", "GLB header").
    [[noreturn]] void fail(std::string_view object, const std::string& what) const;

    // "<object> <index>" or "<object> <index> <name>" when the glTF object is named.
    static std::string label(std::string_view object, int64_t index, std::string_view name = {});

private:
    std::string file_;
};

}  // namespace lf::gltf
