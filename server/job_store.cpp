#include "job_store.h"

#include <unistd.h>

#include <chrono>

namespace lf::server {

namespace {
// Progress events of passes 1..kKeepProgressUpTo and of every power of two
// are kept; of the others only the newest per output.
constexpr int kKeepProgressUpTo = 32;
}  // namespace

std::string default_node_name() {
    char host[256] = {};
    if (gethostname(host, sizeof host - 1) == 0 && host[0]) return host;
    return "lightfarmd";
}

JobStore::JobStore(NodeIdentity node) : node_(std::move(node)) {
    if (node_.name.empty()) node_.name = default_node_name();
}

bool permanent_progress(const nlohmann::json& data) {
    if (data.is_object() && data.value(kAgain, false)) return false;
    const int64_t pass =
        data.is_object() && data.contains("pass") && data["pass"].is_number_integer() ? data["pass"].get<int64_t>() : 0;
    return pass <= kKeepProgressUpTo || (pass & (pass - 1)) == 0;
}

std::string progress_key(const JobEvent& event) {
    const nlohmann::json& d = event.data;
    if (event.type == "preparing") return "preparing";
    return d.is_object() && d.contains("output") && d["output"].is_string() ? d["output"].get<std::string>() : "";
}

bool coalesced_event(const JobEvent& event) {
    return event.type == "progress" ||
           (event.type == "preparing" && event.data.is_object() && event.data.value(kAgain, false));
}

double now_seconds() {
    return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

}  // namespace lf::server
