// The data directory's layout, in one place (docs/service.md, "Where the
// data lives"): a job's files in jobs/ID, an upload in scenes/ID (its files
// under their uploaded names), work in progress in tmp/ (moved into place
// by one rename). Every part of lightfarmd names these paths through here.
#pragma once

#include <filesystem>
#include <string>

namespace lf::server {

class DataDir {
public:
    explicit DataDir(std::filesystem::path root) : root_(std::move(root)) {}

    const std::filesystem::path& root() const { return root_; }
    std::filesystem::path jobs() const { return root_ / "jobs"; }
    std::filesystem::path job(const std::string& id) const { return jobs() / id; }
    std::filesystem::path scenes() const { return root_ / "scenes"; }
    std::filesystem::path scene(const std::string& id) const { return scenes() / id; }
    // A fresh name under tmp/ ("upload-…", "cache-…").
    std::filesystem::path tmp(const std::string& name) const { return root_ / "tmp" / name; }

    // Makes jobs/, scenes/ and tmp/ (they may exist).
    void create() const {
        for (const char* sub : {"jobs", "scenes", "tmp"}) std::filesystem::create_directories(root_ / sub);
    }

private:
    std::filesystem::path root_;
};

}  // namespace lf::server
