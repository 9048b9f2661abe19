#include "metrics.h"

#include <sstream>

namespace lf::server {

namespace {
const std::vector<double> kBuckets = {0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10};
}

void Metrics::set_job_rate(const std::string& job, double rays_per_second) {
    std::lock_guard lock(mutex_);
    job_rates_[job] = rays_per_second;
}

void Metrics::clear_job(const std::string& job) {
    std::lock_guard lock(mutex_);
    job_rates_.erase(job);
}

void Metrics::observe_request(const std::string& route, int status, double seconds) {
    std::lock_guard lock(mutex_);
    Histogram& h = latency_[route];
    if (h.buckets.empty()) h.buckets.assign(kBuckets.size(), 0);
    for (size_t i = 0; i < kBuckets.size(); ++i)
        if (seconds <= kBuckets[i]) ++h.buckets[i];
    ++h.count;
    h.sum += seconds;
    ++requests_[{route, status}];
}

void Metrics::count_refusal(const std::string& reason) {
    std::lock_guard lock(mutex_);
    ++refusals_[reason];
}

std::string Metrics::render(const std::map<protocol::JobState, int>& jobs_by_state) const {
    using protocol::JobState;
    std::ostringstream m;
    m << "# HELP lightfarm_jobs Jobs in the store by state.\n# TYPE lightfarm_jobs gauge\n";
    for (JobState s :
         {JobState::Queued, JobState::Running, JobState::Succeeded, JobState::Failed, JobState::Cancelled}) {
        auto it = jobs_by_state.find(s);
        m << "lightfarm_jobs{state=\"" << protocol::to_string(s) << "\"} "
          << (it == jobs_by_state.end() ? 0 : it->second) << "\n";
    }
    auto queued = jobs_by_state.find(JobState::Queued);
    m << "# HELP lightfarm_queue_depth Jobs waiting for a worker.\n# TYPE lightfarm_queue_depth gauge\n";
    m << "lightfarm_queue_depth " << (queued == jobs_by_state.end() ? 0 : queued->second) << "\n";
    m << "# HELP lightfarm_worker_starts_total Worker processes started.\n# TYPE lightfarm_worker_starts_total "
         "counter\n";
    m << "lightfarm_worker_starts_total " << worker_starts.load() << "\n";
    m << "# HELP lightfarm_worker_failures_total Worker attempts that crashed, hung or ran out of time.\n";
    m << "# TYPE lightfarm_worker_failures_total counter\n";
    m << "lightfarm_worker_failures_total " << worker_failures.load() << "\n";
    m << "# HELP lightfarm_server_faults_total Attempts given back to the queue for a fault of this machine (a full "
         "disk), not counted against the job.\n";
    m << "# TYPE lightfarm_server_faults_total counter\n";
    m << "lightfarm_server_faults_total " << server_faults.load() << "\n";
    m << "# HELP lightfarm_rays_total Rays traced by finished passes.\n# TYPE lightfarm_rays_total counter\n";
    m << "lightfarm_rays_total " << rays_total.load() << "\n";

    m << "# HELP lightfarm_http_connections Open HTTP connections.\n# TYPE lightfarm_http_connections gauge\n";
    m << "lightfarm_http_connections " << http_connections.load() << "\n";
    m << "# HELP lightfarm_http_reading_headers Connections whose request line and headers are still arriving.\n";
    m << "# TYPE lightfarm_http_reading_headers gauge\nlightfarm_http_reading_headers " << http_reading_headers.load()
      << "\n";
    m << "# HELP lightfarm_http_body_reads Request bodies being read on a request thread.\n";
    m << "# TYPE lightfarm_http_body_reads gauge\nlightfarm_http_body_reads " << http_body_reads.load() << "\n";
    m << "# HELP lightfarm_http_idle_dropped_total Idle connections (nothing sent) closed to make room for a new "
         "one at a connection cap.\n";
    m << "# TYPE lightfarm_http_idle_dropped_total counter\n";
    m << "lightfarm_http_idle_dropped_total " << http_idle_dropped.load() << "\n";
    m << "# HELP lightfarm_event_streams Open event streams.\n# TYPE lightfarm_event_streams gauge\n";
    m << "lightfarm_event_streams " << event_streams.load() << "\n";

    std::lock_guard lock(mutex_);
    m << "# HELP lightfarm_http_refused_total Connections and requests refused or ended by the HTTP limits.\n";
    m << "# TYPE lightfarm_http_refused_total counter\n";
    for (const auto& [reason, n] : refusals_)
        m << "lightfarm_http_refused_total{reason=\"" << reason << "\"} " << n << "\n";
    double rate = 0;
    for (const auto& [job, r] : job_rates_) rate += r;
    m << "# HELP lightfarm_rays_per_second Current ray throughput of all running bakes.\n";
    m << "# TYPE lightfarm_rays_per_second gauge\nlightfarm_rays_per_second " << rate << "\n";
    m << "# HELP lightfarm_http_requests_total Requests answered, by route and status.\n";
    m << "# TYPE lightfarm_http_requests_total counter\n";
    for (const auto& [key, n] : requests_)
        m << "lightfarm_http_requests_total{route=\"" << key.first << "\",status=\"" << key.second << "\"} " << n
          << "\n";
    m << "# HELP lightfarm_http_request_seconds Request latency (event streams excluded).\n";
    m << "# TYPE lightfarm_http_request_seconds histogram\n";
    for (const auto& [route, h] : latency_) {
        for (size_t i = 0; i < kBuckets.size(); ++i)
            m << "lightfarm_http_request_seconds_bucket{route=\"" << route << "\",le=\"" << kBuckets[i] << "\"} "
              << h.buckets[i] << "\n";
        m << "lightfarm_http_request_seconds_bucket{route=\"" << route << "\",le=\"+Inf\"} " << h.count << "\n";
        m << "lightfarm_http_request_seconds_sum{route=\"" << route << "\"} " << h.sum << "\n";
        m << "lightfarm_http_request_seconds_count{route=\"" << route << "\"} " << h.count << "\n";
    }
    return m.str();
}

std::string Metrics::render_nodes(const std::string& self, const std::vector<NodeGauge>& nodes) {
    std::ostringstream m;
    m << "# HELP lightfarm_node_info The node that answered this scrape.\n# TYPE lightfarm_node_info gauge\n";
    m << "lightfarm_node_info{node=\"" << self << "\"} 1\n";
    m << "# HELP lightfarm_node_up 1 while a node's heartbeat is younger than its lease.\n";
    m << "# TYPE lightfarm_node_up gauge\n";
    for (const NodeGauge& n : nodes) m << "lightfarm_node_up{node=\"" << n.name << "\"} " << (n.alive ? 1 : 0) << "\n";
    m << "# HELP lightfarm_node_running_jobs Jobs running on each node.\n# TYPE lightfarm_node_running_jobs gauge\n";
    for (const NodeGauge& n : nodes)
        m << "lightfarm_node_running_jobs{node=\"" << n.name << "\"} " << n.running_jobs << "\n";
    m << "# HELP lightfarm_node_heartbeat_age_seconds Seconds since each node's newest heartbeat.\n";
    m << "# TYPE lightfarm_node_heartbeat_age_seconds gauge\n";
    for (const NodeGauge& n : nodes)
        m << "lightfarm_node_heartbeat_age_seconds{node=\"" << n.name << "\"} " << n.seconds_since_heartbeat << "\n";
    return m.str();
}

}  // namespace lf::server
