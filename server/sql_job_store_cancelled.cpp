// The one write to a job after its final state: what its worker wrote in
// the grace it was given after a cancel (its last snapshot), so that the
// job's `latest` is where the bake stood when it was cancelled. Only where
// the job is cancelled and its worker ran on this node; no event (the
// cancelled event stays the job's last).
#include "sql_job_store.h"

namespace lf::server {

void SqlJobStore::set_cancelled_result(const std::string& id, const std::optional<Progress>& progress,
                                       const std::map<std::string, LatestFile>& latest) {
    std::lock_guard lock(mutex_);
    SqlTransaction t(*db_);
    const std::string where = " WHERE id = ? AND state = 'cancelled' AND node = ?";
    if (progress)
        db_->run("cannot store a cancelled job's progress", "UPDATE jobs SET progress = ?" + where,
                 {protocol::to_json(*progress).dump(), id, node().name});
    for (const auto& [output, file] : latest)
        db_->run("cannot store a cancelled job's newest file",
                 std::string("UPDATE jobs SET latest = ") + db_->dialect().latest_with_key + where,
                 {output, protocol::to_json(file).dump(), id, node().name});
    t.commit();
}

}  // namespace lf::server
