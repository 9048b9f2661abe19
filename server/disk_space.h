// The free space of the disk the data directory is on: a server whose disk
// is full stops taking work (503 to uploads and jobs; queued jobs wait) and
// counts a worker's failure then as its own, never the job's.
#pragma once

#include <sys/statvfs.h>

#include <cstdint>
#include <filesystem>
#include <limits>
#include <string>

namespace lf::server {

// Bytes an unprivileged process may still write on `dir`'s filesystem;
// the largest value when it cannot be told.
inline uint64_t free_disk_bytes(const std::filesystem::path& dir) {
    struct statvfs s {};
    if (::statvfs(dir.c_str(), &s) != 0) return std::numeric_limits<uint64_t>::max();
    return uint64_t(s.f_bavail) * uint64_t(s.f_frsize);
}

// "12.5 MB".
inline std::string megabytes(uint64_t bytes) {
    char text[32];
    std::snprintf(text, sizeof text, "%.1f MB", double(bytes) / 1e6);
    return text;
}

}  // namespace lf::server
