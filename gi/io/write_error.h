// A file lightfarm could not write: the disk is full, an I/O error, a
// directory it may not write to. The machine's trouble, never the scene's or
// the settings': `lightfarm bake` exits protocol::kExitMachineFault on it,
// and the server puts the job back in its queue without counting the attempt.
#pragma once

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <string>

namespace lf {

struct WriteError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// "PATH: cannot write (No space left on device)", from errno as the failed call left it.
inline WriteError write_error(const std::filesystem::path& path, int error = errno) {
    return WriteError(path.string() + ": cannot write (" + (error ? std::strerror(error) : "unknown error") + ")");
}

// Creates `dir` and its parents. One it cannot make (a full disk, an I/O
// error) is the machine's trouble like any other write: a WriteError naming
// it, not the filesystem_error of std::filesystem::create_directories.
inline void make_directories(const std::filesystem::path& dir) {
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);
    if (ec) throw write_error(dir, ec.value());
}

}  // namespace lf
