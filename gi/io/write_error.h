// A file lightfarm could not write: the disk is full, an I/O error, a
// directory it may not write to. The machine's trouble, never the scene's or
// the settings': `lightfarm bake` exits protocol::kExitMachineFault on it,
// and the server puts the job back in its queue without counting the attempt.
#pragma once

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

namespace lf {

struct WriteError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// "PATH: cannot write (No space left on device)", from errno as the failed call left it.
inline WriteError write_error(const std::filesystem::path& path, int error = errno) {
    return WriteError(path.string() + ": cannot write (" + (error ? std::strerror(error) : "unknown error") + ")");
}

// Syncs `path` (a file, or a directory after an entry in it changed) to the
// disk; a failure is a WriteError naming `named`.
inline void sync_to_disk(const std::filesystem::path& path, const std::filesystem::path& named) {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) throw write_error(named);
    const int synced = ::fsync(fd);
    const int error = errno;
    ::close(fd);
    if (synced != 0) throw write_error(named, error);
}

// Creates `dir` and its parents, each synced into its parent directory
// once made: commit_file syncs the names of the files in a directory, and a
// power loss must not drop the directory's own name from its parent. One
// it cannot make or sync (a full disk, an I/O error) is the machine's
// trouble like any other write: a WriteError naming it, not the
// filesystem_error of std::filesystem::create_directories.
inline void make_directories(const std::filesystem::path& dir) {
    namespace fs = std::filesystem;
    std::vector<fs::path> missing;  // innermost first
    std::error_code ec;
    for (fs::path p = dir.has_filename() ? dir : dir.parent_path(); !p.empty() && !fs::exists(p, ec);
         p = p.parent_path()) {
        missing.push_back(p);
        if (p == p.parent_path()) break;
    }
    fs::create_directories(dir, ec);
    if (ec) throw write_error(dir, ec.value());
    for (auto made = missing.rbegin(); made != missing.rend(); ++made)
        sync_to_disk(made->has_parent_path() ? made->parent_path() : fs::path("."), *made);
}

// A complete, closed temporary file becomes `path`: synced, renamed into
// place, and the rename synced in its directory, so that a power loss after
// a bake reported its files leaves them whole, not empty (the store that
// recorded the job syncs every commit). A failure leaves no temporary file
// behind and is a WriteError.
inline void commit_file(const std::filesystem::path& tmp, const std::filesystem::path& path) {
    std::error_code ec, ignored;
    try {
        sync_to_disk(tmp, tmp);
    } catch (const WriteError&) {
        std::filesystem::remove(tmp, ignored);
        throw;
    }
    std::filesystem::rename(tmp, path, ec);
    if (ec) {
        std::filesystem::remove(tmp, ignored);
        throw write_error(path, ec.value());
    }
    sync_to_disk(path.parent_path().empty() ? "." : path.parent_path(), path);
}

}  // namespace lf
