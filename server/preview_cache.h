// The previews made of each job's newest lightmap (preview.h), kept while
// that file stays the same, within a byte budget: the least recently shown
// job's leave first. Unbounded, previews of 240 cached jobs held 1 GB of a
// server's memory for good (issue #55). Thread-safe.
#pragma once

#include "preview.h"

#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <string>

namespace lf::server {

class PreviewCache {
public:
    explicit PreviewCache(uint64_t byte_budget) : budget_(byte_budget) {}

    // The previews of job `id` made from `source` (path, size and time of
    // the file they came from), if kept.
    std::optional<std::map<PreviewKind, Preview>> find(const std::string& id, const std::string& source);
    // Keeps them (a job's earlier ones replaced), then drops the least
    // recently found or kept until the whole fits the budget; a set larger
    // than the budget alone is not kept.
    void keep(const std::string& id, const std::string& source, const std::map<PreviewKind, Preview>& previews);
    uint64_t bytes() const;
    size_t jobs() const;

private:
    struct Entry {
        std::string source;
        std::map<PreviewKind, Preview> previews;
        uint64_t bytes = 0;
        uint64_t last_used = 0;
    };
    void drop(std::map<std::string, Entry>::iterator it);

    const uint64_t budget_;
    mutable std::mutex mutex_;
    std::map<std::string, Entry> entries_;  // by job id
    uint64_t bytes_ = 0, clock_ = 0;
};

}  // namespace lf::server
