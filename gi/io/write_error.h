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

}  // namespace lf
