// Counters for GET /metrics, in Prometheus' text exposition format.
#pragma once

#include "job_status.h"

#include <atomic>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace lf::server {

class Metrics {
public:
    std::atomic<uint64_t> worker_starts{0};
    std::atomic<uint64_t> worker_failures{0};  // attempts that crashed, hung or timed out
    std::atomic<uint64_t> server_faults{0};    // attempts given back for a fault of this machine (a full disk)
    std::atomic<uint64_t> rays_total{0};
    // The HTTP layer: open connections, those still sending their request
    // line and headers, request bodies being read, open event streams.
    std::atomic<int64_t> http_connections{0};
    std::atomic<int64_t> http_reading_headers{0};
    std::atomic<int64_t> http_body_reads{0};
    std::atomic<int64_t> event_streams{0};
    // Idle connections (nothing sent) closed to make room for a new one at a cap.
    std::atomic<uint64_t> http_idle_dropped{0};

    // The latest rays/s of a running job (its progress); cleared when it stops.
    void set_job_rate(const std::string& job, double rays_per_second);
    void clear_job(const std::string& job);
    // One answered request, by route pattern ("/v1/jobs/{id}").
    void observe_request(const std::string& route, int status, double seconds);
    // A connection or request refused or ended by the HTTP layer's limits
    // ("connections", "connections_per_address", "event_streams", "header_timeout", ...).
    void count_refusal(const std::string& reason);

    std::string render(const std::map<protocol::JobState, int>& jobs_by_state) const;

    // The nodes sharing the store (GET /v1/nodes), each labelled node="NAME",
    // and which of them answered (lightfarm_node_info).
    struct NodeGauge {
        std::string name;
        bool alive;
        int running_jobs;
        double seconds_since_heartbeat;
    };
    static std::string render_nodes(const std::string& self, const std::vector<NodeGauge>& nodes);

private:
    struct Histogram {
        std::vector<uint64_t> buckets;  // cumulative counts per kBuckets bound
        uint64_t count = 0;
        double sum = 0;
    };
    mutable std::mutex mutex_;
    std::map<std::string, double> job_rates_;
    std::map<std::string, Histogram> latency_;
    std::map<std::pair<std::string, int>, uint64_t> requests_;
    std::map<std::string, uint64_t> refusals_;
};

}  // namespace lf::server
