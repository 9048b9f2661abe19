// How a bake ends other than done: what the CLI and the worker tell apart
// (their exit statuses, protocol/worker_protocol.h), and what the job
// driver and every method may throw.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

namespace lf {

// The job's input cannot be baked as asked (no light, an atlas that cannot
// fit, a mesh that is not there): running it again cannot help. The CLI
// exits with protocol::kExitInputError for it (and for a SceneError).
class BakeInputError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

// A bake stopped on request (stop_request.h) after its last snapshot.
class BakeStopped : public std::runtime_error {
public:
    BakeStopped(std::string output, int pass, std::vector<std::string> files);
    std::string output;              // the output that was passing
    int pass = 0;                    // the pass its last snapshot holds
    std::vector<std::string> files;  // that snapshot's files
};

}  // namespace lf
