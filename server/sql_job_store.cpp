#include "sql_job_store.h"

namespace lf::server {

using nlohmann::json;
using protocol::parse_job_state;
using protocol::to_string;

namespace {

// The jobs table's columns as the store reads and writes them (lease_expires
// aside: no reader needs it).
constexpr const char* kJobColumns =
    "id, owner, scene, spec, state, progress, attempts, max_attempts, max_seconds, error, cause, "
    "cache_key, cached, created_at, started_at, finished_at, latest, node";

// Rows of kJobColumns, in their order.
std::vector<JobRecord> jobs_from(const SqlResult& rows) {
    std::vector<JobRecord> jobs;
    for (size_t i = 0; i < rows.rows.size(); ++i) {
        auto text = [&](int column) { return rows.text(i, column); };
        JobRecord r;
        JobStatus& s = r.status;
        s.id = text(0);
        r.owner = text(1);
        s.scene = text(2);
        s.spec = json::parse(text(3), nullptr, false);
        s.state = parse_job_state(text(4)).value_or(JobState::Failed);
        s.progress = protocol::progress_from_json(json::parse(text(5), nullptr, false));
        s.attempts = int(rows.integer(i, 6));
        s.max_attempts = int(rows.integer(i, 7));
        r.max_seconds = rows.real(i, 8);
        s.error = text(9);
        s.cause = text(10);
        r.cache_key = text(11);
        s.cached = rows.integer(i, 12) != 0;
        s.created_at = rows.real(i, 13);
        s.started_at = rows.real(i, 14);
        s.finished_at = rows.real(i, 15);
        s.latest = protocol::latest_from_json(json::parse(text(16), nullptr, false));
        r.node = text(17);
        jobs.push_back(std::move(r));
    }
    return jobs;
}

std::optional<JobRecord> first(std::vector<JobRecord> jobs) {
    if (jobs.empty()) return std::nullopt;
    return std::move(jobs.front());
}

}  // namespace

SqlJobStore::SqlJobStore(std::unique_ptr<SqlConnection> db, NodeIdentity node)
    : JobStore(std::move(node)), db_(std::move(db)) {}

std::vector<JobRecord> SqlJobStore::select_jobs(const char* what, const std::string& where,
                                                const std::vector<SqlValue>& params) {
    return jobs_from(db_->run(what, std::string("SELECT ") + kJobColumns + " FROM jobs " + where, params));
}

// ---- scenes

std::optional<SceneRecord> SqlJobStore::scene(const std::string& id) {
    std::lock_guard lock(mutex_);
    const SqlResult r = db_->run("cannot read a scene", "SELECT id, main_file, summary FROM scenes WHERE id = ?", {id});
    if (r.empty()) return std::nullopt;
    return SceneRecord{r.text(0, 0), r.text(0, 1), json::parse(r.text(0, 2), nullptr, false)};
}

void SqlJobStore::add_scene(const SceneRecord& scene) {
    std::lock_guard lock(mutex_);
    db_->run("cannot store a scene",
             "INSERT INTO scenes(id, main_file, summary, created_at) VALUES(?, ?, ?, ?) ON CONFLICT DO NOTHING",
             {scene.id, scene.main_file, scene.summary.dump(), now_seconds()});
}

std::optional<SceneRecord> SqlJobStore::scene_for(const std::string& id, const std::string& owner) {
    std::lock_guard lock(mutex_);
    const SqlResult r = db_->run("cannot read a scene",
                                 "SELECT s.id, s.main_file, s.summary, o.name FROM scenes s "
                                 "JOIN scene_owners o ON o.scene = s.id WHERE s.id = ? AND o.owner = ?",
                                 {id, owner});
    if (r.empty()) return std::nullopt;
    SceneRecord scene{r.text(0, 0), r.text(0, 1), json::parse(r.text(0, 2), nullptr, false), r.text(0, 3)};
    // An owner row without a name (one the migration has not reached) is the main file's.
    if (scene.name.empty()) scene.name = scene.main_file;
    return scene;
}

bool SqlJobStore::add_scene_owner(const std::string& id, const std::string& owner, const std::string& name) {
    std::lock_guard lock(mutex_);
    return db_->run("cannot store a scene's owner",
                    "INSERT INTO scene_owners(scene, owner, name) VALUES(?, ?, ?) ON CONFLICT DO NOTHING",
                    {id, owner, name})
               .changed > 0;
}

bool SqlJobStore::scene_owned_by(const std::string& id, const std::string& owner) {
    std::lock_guard lock(mutex_);
    return !db_->run("cannot read a scene's owners", "SELECT 1 FROM scene_owners WHERE scene = ? AND owner = ?",
                     {id, owner})
                .empty();
}

// ---- jobs

void SqlJobStore::insert_job(const JobRecord& job, const std::vector<JobEvent>& events) {
    std::lock_guard lock(mutex_);
    SqlTransaction t(*db_);
    const JobStatus& s = job.status;
    // A job born running (tests, imports) runs on this node, leased from now.
    const bool running = s.state == JobState::Running;
    std::vector<SqlValue> params = {s.id,
                                    job.owner,
                                    s.scene,
                                    s.spec.dump(),
                                    to_string(s.state),
                                    protocol::to_json(s.progress).dump(),
                                    int64_t(s.attempts),
                                    int64_t(s.max_attempts),
                                    job.max_seconds,
                                    s.error,
                                    s.cause,
                                    job.cache_key,
                                    int64_t(s.cached),
                                    s.created_at > 0 ? s.created_at : now_seconds(),
                                    s.started_at,
                                    s.finished_at,
                                    protocol::to_json(s.latest).dump(),
                                    running ? node().name : job.node};
    if (running) params.push_back(node().lease_seconds);
    const std::string lease_expires = running ? std::string(db_->dialect().now) + " + ?" : "0";
    db_->run("cannot store a job",
             std::string("INSERT INTO jobs(") + kJobColumns +
                 ", lease_expires) VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, " + lease_expires + ")",
             params);
    for (const JobEvent& e : events) insert_event_locked(s.id, e);
    t.commit();
}

std::optional<JobRecord> SqlJobStore::job(const std::string& id) {
    std::lock_guard lock(mutex_);
    return first(select_jobs("cannot read a job", "WHERE id = ?", {id}));
}

std::vector<JobRecord> SqlJobStore::jobs_of(const std::string& owner) {
    std::lock_guard lock(mutex_);
    return select_jobs("cannot list jobs", "WHERE owner = ? ORDER BY seq DESC", {owner});
}

int SqlJobStore::queued_count(const std::string& owner) {
    std::lock_guard lock(mutex_);
    return int(
        db_->run("cannot count queued jobs", "SELECT COUNT(*) FROM jobs WHERE owner = ? AND state = 'queued'", {owner})
            .integer(0, 0));
}

int SqlJobStore::queued_ahead(const std::string& id) {
    std::lock_guard lock(mutex_);
    return int(
        db_->run("cannot count the jobs queued before a job",
                 "SELECT COUNT(*) FROM jobs WHERE state = 'queued' AND seq < (SELECT seq FROM jobs WHERE id = ?)", {id})
            .integer(0, 0));
}

std::map<JobState, int> SqlJobStore::count_by_state() {
    std::lock_guard lock(mutex_);
    const SqlResult r = db_->run("cannot count jobs", "SELECT state, COUNT(*) FROM jobs GROUP BY state", {});
    std::map<JobState, int> counts;
    for (size_t i = 0; i < r.rows.size(); ++i)
        if (auto st = parse_job_state(r.text(i, 0))) counts[*st] = int(r.integer(i, 1));
    return counts;
}

std::optional<JobRecord> SqlJobStore::succeeded_with_key(const std::string& cache_key, const std::string& owner) {
    std::lock_guard lock(mutex_);
    return first(
        select_jobs("cannot look up the cache",
                    "WHERE cache_key = ? AND owner = ? AND state = 'succeeded' AND cached = 0 ORDER BY seq LIMIT 1",
                    {cache_key, owner}));
}

std::optional<JobRecord> SqlJobStore::claim_next() {
    std::lock_guard lock(mutex_);
    const SqlDialect& dialect = db_->dialect();
    // One statement: the oldest queued job no other node is claiming right
    // now, running here from the moment it commits.
    return first(jobs_from(db_->run(
        "cannot claim a job",
        std::string("UPDATE jobs SET state = 'running', attempts = attempts + 1, started_at = ?, progress = ?, "
                    "node = ?, lease_expires = ") +
            dialect.now + " + ? WHERE seq = (SELECT seq FROM jobs WHERE state = 'queued' ORDER BY seq LIMIT 1" +
            dialect.for_update_skip_locked + ") RETURNING " + kJobColumns,
        {now_seconds(), protocol::to_json(Progress{}).dump(), node().name, node().lease_seconds})));
}

bool SqlJobStore::renew_lease(const std::string& id) {
    std::lock_guard lock(mutex_);
    return db_->run("cannot renew a lease",
                    std::string("UPDATE jobs SET lease_expires = ") + db_->dialect().now +
                        " + ? WHERE id = ? AND state = 'running' AND node = ?",
                    {node().lease_seconds, id, node().name})
               .changed > 0;
}

std::vector<JobRecord> SqlJobStore::take_over_abandoned(bool at_start) {
    std::lock_guard lock(mutex_);
    const SqlDialect& dialect = db_->dialect();
    // Abandoned: running with its lease expired, or at start held by this
    // node's name (a previous lightfarmd of this node). On a shared database
    // this node's own expired leases count too: it renews its own before it
    // looks (Supervisor::keep_leases), so one is a claim whose answer was lost
    // with the connection. A database of one node (SQLite) counts only other
    // nodes' expired leases (a store copied from elsewhere), and at start
    // every running job: all were left by a previous lightfarmd.
    const std::string abandoned = std::string("state = 'running' AND ((lease_expires < ") + dialect.now +
                                  " AND (node <> ? OR ?)) OR (? AND (node = ? OR ?)))";
    const std::vector<SqlValue> abandoned_params = {node().name, dialect.shared, at_start, node().name,
                                                    !dialect.shared};
    std::vector<JobRecord> found =
        select_jobs("cannot take over jobs of lost nodes", "WHERE " + abandoned + " ORDER BY seq", abandoned_params);
    if (found.empty()) return found;  // the usual answer: one statement
    // Each job to one node: the update takes a job only while it is still
    // abandoned by the node that lost it (another node may have taken it
    // since). The jobs keep `node`: the node that lost them, for the log.
    std::vector<JobRecord> taken;
    SqlTransaction t(*db_);
    for (JobRecord& job : found) {
        std::vector<SqlValue> params = {node().name, node().lease_seconds, job.status.id, job.node};
        params.insert(params.end(), abandoned_params.begin(), abandoned_params.end());
        const SqlResult r = db_->run("cannot take over a job of a lost node",
                                     std::string("UPDATE jobs SET node = ?, lease_expires = ") + dialect.now +
                                         " + ? WHERE id = ? AND node = ? AND " + abandoned,
                                     params);
        if (r.changed > 0) taken.push_back(std::move(job));
    }
    t.commit();
    return taken;
}

void SqlJobStore::set_progress(const std::string& id, const Progress& p) {
    std::lock_guard lock(mutex_);
    db_->run("cannot store progress", "UPDATE jobs SET progress = ? WHERE id = ? AND state = 'running' AND node = ?",
             {protocol::to_json(p).dump(), id, node().name});
}

void SqlJobStore::set_latest(const std::string& id, const std::string& output, const LatestFile& file) {
    std::lock_guard lock(mutex_);
    // One statement: the object's other outputs stay as they are.
    db_->run("cannot store a job's newest file",
             std::string("UPDATE jobs SET latest = ") + db_->dialect().latest_with_key +
                 " WHERE id = ? AND state = 'running' AND node = ?",
             {output, protocol::to_json(file).dump(), id, node().name});
}

// The one write to a job after its final state: what its worker wrote in
// the grace it was given after a cancel (its last snapshot), so that the
// job's `latest` is where the bake stood when it was cancelled. Only where
// the job is cancelled and its worker ran on this node; no event (the
// cancelled event stays the job's last).
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

bool SqlJobStore::requeue(const std::string& id, const JobEvent& event, bool refund_attempt) {
    std::lock_guard lock(mutex_);
    SqlTransaction t(*db_);
    const SqlResult r = db_->run("cannot requeue a job",
                                 "UPDATE jobs SET state = 'queued', attempts = attempts - ?, lease_expires = 0 "
                                 "WHERE id = ? AND state = 'running' AND node = ?",
                                 {int64_t(refund_attempt ? 1 : 0), id, node().name});
    if (r.changed == 0) return false;
    insert_event_locked(id, event);
    t.commit();
    return true;
}

bool SqlJobStore::finish(const std::string& id, JobState state, const std::string& error, const std::string& cause,
                         const JobEvent& event) {
    std::lock_guard lock(mutex_);
    SqlTransaction t(*db_);
    const SqlResult r = db_->run("cannot finish a job",
                                 "UPDATE jobs SET state = ?, error = ?, cause = ?, finished_at = ?, lease_expires = 0 "
                                 "WHERE id = ? AND state IN ('queued', 'running')",
                                 {to_string(state), error, cause, now_seconds(), id});
    if (r.changed == 0) return false;
    insert_event_locked(id, event);
    t.commit();
    return true;
}

std::vector<JobRecord> SqlJobStore::running_jobs() {
    std::lock_guard lock(mutex_);
    return select_jobs("cannot list running jobs", "WHERE state = 'running' ORDER BY seq", {});
}

std::vector<double> SqlJobStore::recent_job_seconds(int n) {
    std::lock_guard lock(mutex_);
    const SqlResult r = db_->run("cannot read finished jobs",
                                 "SELECT finished_at - started_at FROM jobs WHERE state = 'succeeded' AND cached = 0 "
                                 "AND started_at > 0 AND finished_at >= started_at ORDER BY finished_at DESC LIMIT ?",
                                 {int64_t(n)});
    std::vector<double> seconds;
    for (size_t i = 0; i < r.rows.size(); ++i) seconds.push_back(r.real(i, 0));
    return seconds;
}

bool SqlJobStore::empty() {
    std::lock_guard lock(mutex_);
    return db_->run("cannot count jobs and scenes",
                    "SELECT (SELECT COUNT(*) FROM jobs) + (SELECT COUNT(*) FROM scenes)", {})
               .integer(0, 0) == 0;
}

bool SqlJobStore::has_job(const std::string& id) {
    std::lock_guard lock(mutex_);
    return !db_->run("cannot read a job", "SELECT 1 FROM jobs WHERE id = ?", {id}).empty();
}

// ---- events

int64_t SqlJobStore::insert_event_locked(const std::string& id, const JobEvent& event) {
    // A progress event replaces the older non-permanent one of its output
    // (append_event's coalescing). The new id is taken while the replaced
    // event still counts: it may be the newest, and an id is never given twice.
    const bool progress = coalesced_event(event);
    const SqlValue key = progress ? SqlValue(progress_key(event)) : SqlValue(nullptr);
    const int64_t permanent = progress && !permanent_progress(event.data) ? 0 : 1;
    const std::string next_id = "next AS (SELECT COALESCE(MAX(id), 0) + 1 AS id FROM events WHERE job = ?)";
    const std::string replaced = "DELETE FROM events WHERE job = ? AND coalesce_key = ? AND permanent = 0";
    // (CAST: PostgreSQL reads an untyped parameter in a SELECT list as text.)
    const std::string insert =
        "INSERT INTO events(job, id, type, data, coalesce_key, permanent) "
        "SELECT ?, next.id, ?, ?, ?, CAST(? AS INTEGER) FROM next RETURNING id";
    const std::vector<SqlValue> row = {id, event.type, event.data.dump(), key, permanent};

    if (progress && db_->dialect().writable_ctes) {
        // One statement, one snapshot: the id is taken before the replaced event goes.
        std::vector<SqlValue> params = {id, id, key};
        params.insert(params.end(), row.begin(), row.end());
        return db_->run("cannot store an event", "WITH " + next_id + ", gone AS (" + replaced + ") " + insert, params)
            .integer(0, 0);
    }
    std::vector<SqlValue> params = {id};
    params.insert(params.end(), row.begin(), row.end());
    const int64_t event_id = db_->run("cannot store an event", "WITH " + next_id + " " + insert, params).integer(0, 0);
    // Without a DELETE inside WITH (SQLite), the replaced event goes once the
    // new one is in, its id taken; the new one stays.
    if (progress) db_->run("cannot store an event", replaced + " AND id < ?", {id, key, event_id});
    return event_id;
}

int64_t SqlJobStore::append_event(const std::string& id, const JobEvent& event) {
    std::lock_guard lock(mutex_);
    SqlTransaction t(*db_);
    // The job's row lock orders this event after every other of the job.
    if (db_->run("cannot lock a job",
                 std::string("SELECT 1 FROM jobs WHERE id = ? AND state = 'running' AND node = ?") +
                     db_->dialect().for_update,
                 {id, node().name})
            .empty())
        return 0;
    const int64_t event_id = insert_event_locked(id, event);
    t.commit();
    return event_id;
}

std::vector<JobEvent> SqlJobStore::events_after(const std::string& id, int64_t after) {
    std::lock_guard lock(mutex_);
    const SqlResult r = db_->run("cannot read events",
                                 "SELECT id, type, data FROM events WHERE job = ? AND id > ? ORDER BY id", {id, after});
    std::vector<JobEvent> events;
    for (size_t i = 0; i < r.rows.size(); ++i)
        events.push_back(JobEvent{r.integer(i, 0), r.text(i, 1), json::parse(r.text(i, 2), nullptr, false)});
    return events;
}

int64_t SqlJobStore::compact_events(double finished_before) {
    std::lock_guard lock(mutex_);
    return db_
        ->run("cannot compact events",
              "DELETE FROM events WHERE coalesce_key IS NOT NULL AND job IN "
              "(SELECT id FROM jobs WHERE state IN ('succeeded', 'failed', 'cancelled') AND finished_at < ?) "
              "AND id < (SELECT MAX(e.id) FROM events e WHERE e.job = events.job "
              "AND e.coalesce_key = events.coalesce_key)",
              {finished_before})
        .changed;
}

// ---- nodes

void SqlJobStore::heartbeat(const json& info) {
    std::lock_guard lock(mutex_);
    const std::string now = db_->dialect().now;
    db_->run("cannot store the node's heartbeat",
             "INSERT INTO nodes(name, started_at, heartbeat_at, info) VALUES(?, " + now + ", " + now +
                 ", ?) ON CONFLICT(name) DO UPDATE SET heartbeat_at = excluded.heartbeat_at, info = excluded.info",
             {node().name, info.dump()});
}

std::vector<NodeRecord> SqlJobStore::nodes() {
    std::lock_guard lock(mutex_);
    const SqlResult r = db_->run("cannot list nodes",
                                 std::string("SELECT name, started_at, heartbeat_at, ") + db_->dialect().now +
                                     " - heartbeat_at, info FROM nodes ORDER BY name",
                                 {});
    std::vector<NodeRecord> nodes;
    for (size_t i = 0; i < r.rows.size(); ++i)
        nodes.push_back(
            {r.text(i, 0), r.real(i, 1), r.real(i, 2), r.real(i, 3), json::parse(r.text(i, 4), nullptr, false)});
    return nodes;
}

}  // namespace lf::server
