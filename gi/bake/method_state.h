// Resuming a bake (issue #9): what a method's passes carry from one pass to
// the next, written beside the job's snapshots so that a bake whose worker
// died (a node killed, a lost GPU) continues from its last snapshot instead
// of from pass 0. Every method's random numbers are keyed by (seed, pass,
// element), never drawn from a running generator, so the restored buffers and
// pass count are all a method needs: a resumed bake traces exactly the rays
// the uninterrupted one would have (the lightmap's, with the same passes per
// dispatch: a state from another device's count is taken, and continues
// with this one's).
//
// In the job's output directory, beside its snapshots:
//   .resume/<output>.state      the latest state (binary, below)
//   .resume/<output>.done.json  the output finished: its result, to reuse
// The job driver removes .resume/ once the job is done.
#pragma once

#include "bake/progressive.h"
#include "util/hash.h"
#include "gpu/shader.h"

#include <nlohmann/json.hpp>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace lf {

struct MethodState {
    // What the state belongs to: the method's settings (the atlas's
    // included), so that a state is never restored into a different bake.
    std::string key;
    // A hash of the method's element layout (which atlas texel, vertex or
    // probe each buffer entry is): the same description could in principle
    // come from a different packing.
    uint64_t layout = 0;
    PassStats stats;
    std::vector<int64_t> counters;                // the method's own (texels still tracing, …)
    std::vector<std::vector<std::byte>> buffers;  // the GPU buffers, in the method's order
    std::vector<std::string> files;               // snapshots written so far, oldest first
};

// A state that cannot be resumed from: another bake's, a different layout, a
// damaged or truncated file. The bake starts from pass 0 and says why.
class MethodStateMismatch : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

// The file format: "LFSTATE1", a little-endian uint64 header length, the
// header (JSON: key, layout, stats, counters, files, buffer sizes), the
// buffers' bytes, and a uint64 checksum of everything before it.
void write_method_state(const std::filesystem::path& path, const MethodState& state);
// Throws MethodStateMismatch (naming the file) for a file that is not a
// complete state.
MethodState read_method_state(const std::filesystem::path& path);

// A GPU buffer's bytes (on the GL thread), and back: restore_buffers
// uploads a state's buffers into a method's (named, for the message) once
// every size is checked, and throws MethodStateMismatch, changing nothing,
// when the count or a size differs.
std::vector<std::byte> buffer_bytes(const GpuBuffer& buffer);
void restore_buffers(const std::vector<std::pair<GpuBuffer*, std::string>>& to,
                     const std::vector<std::vector<std::byte>>& from);

}  // namespace lf
