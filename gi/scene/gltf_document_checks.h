// The JSON-level checks behind read_document() (internal to gi/scene).
#pragma once

#include "scene/gltf_errors.h"
#include "scene/gltf_files.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace lf::gltf {

class DocumentChecker {
public:
    DocumentChecker(const nlohmann::json& root, bool binary, const LoadLimits& limits, const Errors& errors)
        : root_(root), binary_(binary), limits_(limits), errors_(errors) {}

    // Runs every check; approves the external files tinygltf may read.
    void check(uint64_t bin_chunk_size, bool has_bin_chunk, SceneFiles& files, std::vector<std::string>* warnings);

    const std::vector<bool>& used_images() const { return used_images_; }

private:
    static const nlohmann::json* member(const nlohmann::json& object, const char* key);
    // A top-level array ("buffers", ...), empty when absent.
    const nlohmann::json& array(const char* key) const;
    const nlohmann::json& object_at(const nlohmann::json& items, size_t index, std::string_view what) const;
    uint64_t unsigned_field(const nlohmann::json& object, const char* key, const std::string& where, bool required,
                            uint64_t fallback) const;
    // An index into the top-level array `target`; -1 when absent and not required.
    int64_t index_field(const nlohmann::json& object, const char* key, const std::string& where, const char* target,
                        bool required) const;

    void check_asset() const;
    void check_extensions(std::vector<std::string>* warnings) const;
    void find_used_images();
    void check_buffers(uint64_t bin_chunk_size, bool has_bin_chunk, SceneFiles& files);
    void check_buffer_views() const;
    void check_accessors() const;
    void check_sparse(const nlohmann::json& sparse, const std::string& accessor) const;
    void check_images(SceneFiles& files, std::vector<std::string>* warnings);
    void plan_external_read(const std::string& where, const std::string& uri, uint64_t size, const SceneFiles& files);

    const nlohmann::json& root_;
    bool binary_;
    const LoadLimits& limits_;
    const Errors& errors_;
    std::vector<bool> used_images_;
    uint64_t planned_bytes_ = 0;
};

}  // namespace lf::gltf
