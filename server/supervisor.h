// Runs queued jobs in worker processes (`lightfarm bake ... --json`) and turns
// what they print into progress, events and a final state.
//
// The worker contract: one JSON object per stdout line,
//   {"event":"start","renderer":...,"vendor":...,"texels":N}
//   {"event":"progress","pass":P,"rays":R,"seconds":S,"error_estimate":E}
//   {"event":"snapshot","file":"lightmap.pass-0004.exr","pass":4}
//   {"event":"done","files":[...],"pass":P,"rays":R,"seconds":S,"error_estimate":E}
// exit 0 on success; otherwise nonzero with a one-line error on stderr.
// A worker that exits otherwise, is killed by a signal, prints nothing for
// --stall-timeout seconds or runs past the job's deadline costs the job one
// attempt; after the last one the job fails with that cause. Nothing a worker
// does can stop the server.
#pragma once

#include "config.h"
#include "events.h"
#include "job_store.h"
#include "metrics.h"

#include <atomic>
#include <filesystem>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

namespace lf::server {

class Supervisor {
public:
    Supervisor(JobStore& store, const ServerConfig& config, ChangeSignal& changes, Metrics& metrics);
    ~Supervisor();  // stop()

    // Requeues jobs a previous lightfarmd left running (one attempt counted;
    // failed when none is left), then starts the worker threads.
    void start();
    // Kills running workers and puts their jobs back in the queue without
    // counting the attempt: a restart is not the job's fault.
    void stop();

    // The job was marked cancelled in the store; kill its worker if it runs here.
    void cancel(const std::string& job_id);

    std::filesystem::path job_dir(const std::string& job_id) const;
    std::filesystem::path scene_path(const SceneRecord& scene) const;

private:
    // `device`: the engine's --device for this worker ("" = its default).
    void worker_loop(const std::string& device);
    int count_gpus() const;
    void run_attempt(const JobRecord& job, const std::string& device);
    void attempt_failed(const JobRecord& job, const std::string& cause);

    JobStore& store_;
    const ServerConfig& config_;
    ChangeSignal& changes_;
    Metrics& metrics_;
    std::string engine_;
    std::atomic<bool> stopping_{false};
    std::vector<std::thread> threads_;
    std::mutex cancel_mutex_;
    std::set<std::string> cancelled_;  // running here, to be killed
};

}  // namespace lf::server
