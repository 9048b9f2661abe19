// The writers and readers every method shares: multi-channel float OpenEXR
// (lightmaps, SH per texel, probes), PFM (reference masks), and atomic file
// replacement, so a reader never sees half a file.
#pragma once

#include <filesystem>
#include <functional>
#include <map>
#include <ostream>
#include <string>
#include <vector>

namespace lf {

// A float image with named channels ("R", "G", "B", "direct.R", "samples" …),
// rows from the top, as OpenEXR stores them.
struct FloatImage {
    int width = 0;
    int height = 0;
    std::map<std::string, std::vector<float>> channels;    // each width*height
    std::map<std::string, std::string> string_attributes;  // header attributes
    std::map<std::string, double> number_attributes;

    std::vector<float>& channel(const std::string& name) {
        auto& c = channels[name];
        c.resize(size_t(width) * size_t(height), 0.0f);
        return c;
    }
    const std::vector<float>& at(const std::string& name) const;  // throws if missing
};

// Writes FLOAT channels, ZIP-compressed, atomically (temp file + rename).
// The writers throw WriteError (io/write_error.h) when the file cannot be
// written, leaving no temporary file behind.
void write_exr(const std::filesystem::path& path, const FloatImage& image);
FloatImage read_exr(const std::filesystem::path& path);

// Portable float map ("PF" colour or "Pf" grey): returned rows from the top
// (PFM stores them bottom to top), 3 channels R, G, B (or "Y").
FloatImage read_pfm(const std::filesystem::path& path);

// Writes a file atomically: `write` fills a temp file in the same directory,
// which is renamed to `path` once complete (a reader sees all or nothing).
void write_file_atomic(const std::filesystem::path& path, const std::function<void(std::ostream&)>& write);
void write_file_atomic(const std::filesystem::path& path, const std::string& bytes);

}  // namespace lf
