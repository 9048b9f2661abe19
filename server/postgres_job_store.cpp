#include "postgres_job_store.h"

#include <libpq-fe.h>

#include <cstdio>
#include <stdexcept>

namespace lf::server {

using nlohmann::json;
using protocol::parse_job_state;
using protocol::to_string;

namespace {

// The schema, one migration per version, applied in order at start and
// recorded in schema_version. A released migration is never edited: a change
// is a new one at the end (and kSchemaVersion follows it).
struct Migration {
    int version;
    const char* sql;
};
constexpr Migration kMigrations[] = {
    {1, R"sql(
CREATE TABLE scenes(
  id TEXT PRIMARY KEY, main_file TEXT NOT NULL, summary TEXT NOT NULL, created_at DOUBLE PRECISION NOT NULL);
CREATE TABLE scene_owners(
  scene TEXT NOT NULL, owner TEXT NOT NULL, PRIMARY KEY(scene, owner));
CREATE TABLE jobs(
  seq BIGSERIAL PRIMARY KEY,
  id TEXT UNIQUE NOT NULL, owner TEXT NOT NULL, scene TEXT NOT NULL, spec TEXT NOT NULL,
  state TEXT NOT NULL, progress TEXT NOT NULL, attempts INTEGER NOT NULL, max_attempts INTEGER NOT NULL,
  max_seconds DOUBLE PRECISION NOT NULL, error TEXT NOT NULL, cause TEXT NOT NULL, cache_key TEXT NOT NULL,
  cached INTEGER NOT NULL, created_at DOUBLE PRECISION NOT NULL, started_at DOUBLE PRECISION NOT NULL,
  finished_at DOUBLE PRECISION NOT NULL, latest TEXT NOT NULL DEFAULT '{}',
  node TEXT NOT NULL DEFAULT '', lease_expires DOUBLE PRECISION NOT NULL DEFAULT 0);
CREATE INDEX jobs_by_owner ON jobs(owner, seq);
CREATE INDEX jobs_by_state ON jobs(state, seq);
CREATE INDEX jobs_by_key ON jobs(cache_key, state);
CREATE TABLE events(
  job TEXT NOT NULL, id BIGINT NOT NULL, type TEXT NOT NULL, data TEXT NOT NULL,
  coalesce_key TEXT, permanent INTEGER NOT NULL DEFAULT 1, PRIMARY KEY(job, id));
CREATE TABLE nodes(
  name TEXT PRIMARY KEY, started_at DOUBLE PRECISION NOT NULL, heartbeat_at DOUBLE PRECISION NOT NULL,
  info TEXT NOT NULL);
)sql"},
};
static_assert(std::size(kMigrations) == PostgresJobStore::kSchemaVersion, "one migration per schema version");

// Leases and heartbeats are timed by the database's clock: the nodes' clocks
// may disagree, the database's is one.
constexpr const char* kDbNow = "extract(epoch from clock_timestamp())";

// Any key: migrations of nodes starting together run one after the other.
constexpr const char* kMigrationLock = "SELECT pg_advisory_xact_lock(7023651744)";

// '?' placeholders (the SQLite store's) as PostgreSQL's $1, $2, ...
std::string numbered_placeholders(const std::string& sql) {
    std::string out;
    int n = 0;
    for (char c : sql) {
        if (c == '?') out += "$" + std::to_string(++n);
        else out += c;
    }
    return out;
}

std::string number(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

std::string describe_database(PGconn* conn) {
    const char* user = PQuser(conn);
    const char* host = PQhost(conn);
    const char* port = PQport(conn);
    const char* db = PQdb(conn);
    return std::string(user ? user : "?") + "@" + (host ? host : "?") + ":" + (port ? port : "?") + "/" +
           (db ? db : "?");
}

std::string first_line(const char* message) {
    std::string m = message ? message : "";
    while (!m.empty() && (m.back() == '\n' || m.back() == ' ')) m.pop_back();
    return m;
}

}  // namespace

// One statement's result, freed with it.
class PostgresJobStore::Result {
public:
    explicit Result(PGresult* r) : r_(r) {}
    Result(Result&& o) noexcept : r_(o.r_) { o.r_ = nullptr; }
    Result(const Result&) = delete;
    Result& operator=(const Result&) = delete;
    ~Result() { PQclear(r_); }
    int rows() const { return PQntuples(r_); }
    std::string text(int row, int column) const {
        return std::string(PQgetvalue(r_, row, column), size_t(PQgetlength(r_, row, column)));
    }
    int64_t integer(int row, int column) const { return std::stoll(text(row, column)); }
    double real(int row, int column) const { return std::stod(text(row, column)); }
    bool ok() const {
        const ExecStatusType s = PQresultStatus(r_);  // PGRES_FATAL_ERROR for a null result (out of memory)
        return s == PGRES_COMMAND_OK || s == PGRES_TUPLES_OK;
    }
    int affected() const {
        const char* n = PQcmdTuples(r_);
        return n && n[0] ? std::stoi(n) : 0;
    }

private:
    PGresult* r_;
};

// BEGIN ... COMMIT; leaving the scope without commit() rolls back.
class PostgresJobStore::Transaction {
public:
    explicit Transaction(PostgresJobStore& store) : store_(store) { store_.run("cannot begin a transaction", "BEGIN"); }
    ~Transaction() {
        if (!done_) PQclear(PQexec(store_.conn_, "ROLLBACK"));  // best effort: a lost connection rolled back already
    }
    Transaction(const Transaction&) = delete;
    Transaction& operator=(const Transaction&) = delete;
    void commit() {
        done_ = true;
        store_.run("commit failed", "COMMIT");
    }

private:
    PostgresJobStore& store_;
    bool done_ = false;
};

PostgresJobStore::PostgresJobStore(const std::string& uri, NodeIdentity node) : JobStore(std::move(node)), uri_(uri) {
    char* error = nullptr;
    PQconninfoOption* options = PQconninfoParse(uri.c_str(), &error);
    if (!options) {
        const std::string why = error ? first_line(error) : "out of memory";
        PQfreemem(error);
        throw std::invalid_argument("--store: '" + uri + "' is not a PostgreSQL connection URI (" + why +
                                    "); write postgresql://USER@HOST:PORT/DB");
    }
    PQconninfoFree(options);
    connect_if_lost();
    migrate();
}

PostgresJobStore::~PostgresJobStore() { PQfinish(conn_); }

void PostgresJobStore::connect_if_lost() {
    if (conn_ && PQstatus(conn_) == CONNECTION_OK) return;
    if (conn_) {
        PQreset(conn_);
    } else {
        // The URI's own settings win over these defaults (they come last).
        // Keepalives: a cut network ends the connection in ~25 s instead of
        // hanging a call; the timeouts bound a call that waits on a lock.
        const char* keys[] = {"connect_timeout",  "application_name", "keepalives_idle", "keepalives_interval",
                              "keepalives_count", "options",          "dbname",          nullptr};
        const char* values[] = {"5",          "lightfarmd", "10",
                                "5",          "3",          "-c lock_timeout=10000 -c statement_timeout=30000",
                                uri_.c_str(), nullptr};
        conn_ = PQconnectdbParams(keys, values, 1);
        if (!conn_) throw StoreError("job store: cannot connect to PostgreSQL: out of memory");
        where_ = describe_database(conn_);
        // Notices ("relation already exists, skipping") are not errors: not for the log.
        PQsetNoticeProcessor(
            conn_, [](void*, const char*) {}, nullptr);
    }
    if (PQstatus(conn_) != CONNECTION_OK)
        throw StoreError("job store: cannot connect to PostgreSQL at " + where_ + ": " +
                         first_line(PQerrorMessage(conn_)));
}

PostgresJobStore::Result PostgresJobStore::run(const char* what, const std::string& sql,
                                               const std::vector<Param>& params) {
    connect_if_lost();
    std::vector<const char*> values;
    for (const Param& p : params) values.push_back(p ? p->c_str() : nullptr);
    ++statements_;
    // Without parameters, the simple protocol: it also takes several commands (a migration).
    Result r(params.empty() ? PQexec(conn_, sql.c_str())
                            : PQexecParams(conn_, numbered_placeholders(sql).c_str(), int(values.size()), nullptr,
                                           values.data(), nullptr, nullptr, 0));
    if (!r.ok()) {
        const bool lost = PQstatus(conn_) != CONNECTION_OK;
        throw StoreError(std::string("job store: ") + what + ": " +
                         (lost ? "lost the connection to PostgreSQL at " + where_ + ": " : "") +
                         first_line(PQerrorMessage(conn_)));
    }
    return r;
}

void PostgresJobStore::migrate() {
    Transaction t(*this);
    run("cannot lock the schema", kMigrationLock);
    run("cannot create schema_version", "CREATE TABLE IF NOT EXISTS schema_version(version INTEGER NOT NULL)");
    const int current =
        int(run("cannot read schema_version", "SELECT COALESCE(MAX(version), 0) FROM schema_version").integer(0, 0));
    if (current > kSchemaVersion)
        throw std::runtime_error("the job store at " + where_ + " has schema version " + std::to_string(current) +
                                 ", newer than this lightfarmd knows (" + std::to_string(kSchemaVersion) +
                                 "): a newer lightfarmd migrated it. Run that version here too (every node of a "
                                 "store must be at least as new as its schema)");
    for (const Migration& m : kMigrations) {
        if (m.version <= current) continue;
        const std::string what = "schema migration to version " + std::to_string(m.version) + " failed";
        run(what.c_str(), m.sql);
        run(what.c_str(), "INSERT INTO schema_version(version) VALUES(?)", {std::to_string(m.version)});
    }
    t.commit();
}

std::optional<SceneRecord> PostgresJobStore::scene(const std::string& id) {
    std::lock_guard lock(mutex_);
    const Result r = run("cannot read a scene", "SELECT id, main_file, summary FROM scenes WHERE id = ?", {id});
    if (r.rows() == 0) return std::nullopt;
    return SceneRecord{r.text(0, 0), r.text(0, 1), json::parse(r.text(0, 2), nullptr, false)};
}

void PostgresJobStore::add_scene(const SceneRecord& scene) {
    std::lock_guard lock(mutex_);
    run("cannot store a scene",
        "INSERT INTO scenes(id, main_file, summary, created_at) VALUES(?, ?, ?, ?) ON CONFLICT DO NOTHING",
        {scene.id, scene.main_file, scene.summary.dump(), number(now_seconds())});
}

bool PostgresJobStore::add_scene_owner(const std::string& id, const std::string& owner) {
    std::lock_guard lock(mutex_);
    return run("cannot store a scene's owner",
               "INSERT INTO scene_owners(scene, owner) VALUES(?, ?) ON CONFLICT DO NOTHING", {id, owner})
               .affected() > 0;
}

bool PostgresJobStore::scene_owned_by(const std::string& id, const std::string& owner) {
    std::lock_guard lock(mutex_);
    return run("cannot read a scene's owners", "SELECT 1 FROM scene_owners WHERE scene = ? AND owner = ?", {id, owner})
               .rows() > 0;
}

int64_t PostgresJobStore::insert_event_locked(const std::string& id, const JobEvent& event) {
    // The caller holds the job's row lock (or inserted the job): event ids of
    // one job are given one at a time, in commit order. The id is taken
    // before the replaced progress event goes (one statement, one snapshot):
    // the event a progress event replaces may be the newest, and an id is
    // never given twice.
    const bool progress = event.type == "progress";
    const std::string permanent = progress && !permanent_progress(event.data) ? "0" : "1";
    const Param key = progress ? Param(progress_key(event)) : std::nullopt;
    const std::string replaced = progress ? ", gone AS (DELETE FROM events WHERE job = ? AND coalesce_key = ? "
                                            "AND permanent = 0) "
                                          : " ";
    std::vector<Param> params = {id};
    if (progress) params.insert(params.end(), {id, key});
    params.insert(params.end(), {id, event.type, event.data.dump(), key, permanent});
    const Result r = run("cannot store an event",
                         "WITH next AS (SELECT COALESCE(MAX(id), 0) + 1 AS id FROM events WHERE job = ?)" + replaced +
                             "INSERT INTO events(job, id, type, data, coalesce_key, permanent) "
                             "SELECT ?, next.id, ?, ?, ?, CAST(? AS INTEGER) FROM next RETURNING id",
                         params);
    return r.integer(0, 0);
}

void PostgresJobStore::insert_job(const JobRecord& job, const std::vector<JobEvent>& events) {
    std::lock_guard lock(mutex_);
    Transaction t(*this);
    const JobStatus& s = job.status;
    // A job born running (tests, imports) runs on this node.
    const bool running = s.state == JobState::Running;
    run("cannot store a job",
        std::string("INSERT INTO jobs(") + kJobColumns +
            ", lease_expires) VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, " +
            (running ? std::string(kDbNow) + " + " + number(node().lease_seconds) : "0") + ")",
        {s.id, job.owner, s.scene, s.spec.dump(), to_string(s.state), protocol::to_json(s.progress).dump(),
         std::to_string(s.attempts), std::to_string(s.max_attempts), number(job.max_seconds), s.error, s.cause,
         job.cache_key, s.cached ? "1" : "0", number(s.created_at > 0 ? s.created_at : now_seconds()),
         number(s.started_at), number(s.finished_at), protocol::to_json(s.latest).dump(),
         running ? node().name : job.node});
    for (const JobEvent& e : events) insert_event_locked(s.id, e);
    t.commit();
}

std::vector<JobRecord> PostgresJobStore::jobs_from(const Result& rows, int first) const {
    std::vector<JobRecord> jobs;
    for (int i = 0; i < rows.rows(); ++i) {
        auto text = [&](int column) { return rows.text(i, first + column); };
        JobRecord r;
        JobStatus& s = r.status;
        s.id = text(0);
        r.owner = text(1);
        s.scene = text(2);
        s.spec = json::parse(text(3), nullptr, false);
        s.state = parse_job_state(text(4)).value_or(JobState::Failed);
        s.progress = protocol::progress_from_json(json::parse(text(5), nullptr, false));
        s.attempts = std::stoi(text(6));
        s.max_attempts = std::stoi(text(7));
        r.max_seconds = std::stod(text(8));
        s.error = text(9);
        s.cause = text(10);
        r.cache_key = text(11);
        s.cached = text(12) != "0";
        s.created_at = std::stod(text(13));
        s.started_at = std::stod(text(14));
        s.finished_at = std::stod(text(15));
        s.latest = protocol::latest_from_json(json::parse(text(16), nullptr, false));
        r.node = text(17);
        jobs.push_back(std::move(r));
    }
    return jobs;
}

std::vector<JobRecord> PostgresJobStore::select_jobs(const char* what, const std::string& where,
                                                     const std::vector<Param>& params) {
    return jobs_from(run(what, std::string("SELECT ") + kJobColumns + " FROM jobs " + where, params));
}

std::optional<JobRecord> PostgresJobStore::job(const std::string& id) {
    std::lock_guard lock(mutex_);
    auto jobs = select_jobs("cannot read a job", "WHERE id = ?", {id});
    if (jobs.empty()) return std::nullopt;
    return jobs.front();
}

std::vector<JobRecord> PostgresJobStore::jobs_of(const std::string& owner) {
    std::lock_guard lock(mutex_);
    return select_jobs("cannot list jobs", "WHERE owner = ? ORDER BY seq DESC", {owner});
}

int PostgresJobStore::queued_count(const std::string& owner) {
    std::lock_guard lock(mutex_);
    return int(
        run("cannot count queued jobs", "SELECT COUNT(*) FROM jobs WHERE owner = ? AND state = 'queued'", {owner})
            .integer(0, 0));
}

std::map<JobState, int> PostgresJobStore::count_by_state() {
    std::lock_guard lock(mutex_);
    const Result r = run("cannot count jobs", "SELECT state, COUNT(*) FROM jobs GROUP BY state");
    std::map<JobState, int> counts;
    for (int i = 0; i < r.rows(); ++i)
        if (auto st = parse_job_state(r.text(i, 0))) counts[*st] = int(r.integer(i, 1));
    return counts;
}

std::optional<JobRecord> PostgresJobStore::succeeded_with_key(const std::string& cache_key) {
    std::lock_guard lock(mutex_);
    auto jobs =
        select_jobs("cannot look up the cache",
                    "WHERE cache_key = ? AND state = 'succeeded' AND cached = 0 ORDER BY seq LIMIT 1", {cache_key});
    if (jobs.empty()) return std::nullopt;
    return jobs.front();
}

std::optional<JobRecord> PostgresJobStore::claim_next() {
    std::lock_guard lock(mutex_);
    // One statement: the oldest queued job no other node is claiming right
    // now (SKIP LOCKED), running here from the moment it commits.
    auto jobs = jobs_from(
        run("cannot claim a job",
            std::string("UPDATE jobs SET state = 'running', attempts = attempts + 1, started_at = ?, "
                        "progress = ?, node = ?, lease_expires = ") +
                kDbNow +
                " + ? WHERE seq = (SELECT seq FROM jobs WHERE state = 'queued' "
                "ORDER BY seq LIMIT 1 FOR UPDATE SKIP LOCKED) RETURNING " +
                kJobColumns,
            {number(now_seconds()), protocol::to_json(Progress{}).dump(), node().name, number(node().lease_seconds)}));
    if (jobs.empty()) return std::nullopt;
    return jobs.front();
}

bool PostgresJobStore::renew_lease(const std::string& id) {
    std::lock_guard lock(mutex_);
    return run("cannot renew a lease",
               std::string("UPDATE jobs SET lease_expires = ") + kDbNow +
                   " + ? WHERE id = ? AND state = 'running' AND node = ?",
               {number(node().lease_seconds), id, node().name})
               .affected() > 0;
}

std::vector<JobRecord> PostgresJobStore::take_over_abandoned(bool at_start) {
    std::lock_guard lock(mutex_);
    // Expired leases of any node: this node renews its own before it looks
    // (Supervisor::keep_leases), so an expired one of its own is a claim
    // whose answer was lost with the connection. SKIP LOCKED: each job to
    // one node. RETURNING gives the node that lost it.
    const Result r =
        run("cannot take over jobs of lost nodes",
            std::string("WITH gone AS (SELECT seq AS gone_seq, node AS lost_node FROM jobs WHERE state = 'running' "
                        "AND (lease_expires < ") +
                kDbNow + " OR (node = ? AND ?)) ORDER BY seq FOR UPDATE SKIP LOCKED) " +
                "UPDATE jobs SET node = ?, lease_expires = " + kDbNow + " + ? FROM gone WHERE seq = gone_seq " +
                "RETURNING " + kJobColumns + ", lost_node",
            {node().name, at_start ? "true" : "false", node().name, number(node().lease_seconds)});
    std::vector<JobRecord> jobs = jobs_from(r);
    for (size_t i = 0; i < jobs.size(); ++i) jobs[i].node = r.text(int(i), 18);
    return jobs;
}

void PostgresJobStore::set_progress(const std::string& id, const Progress& p) {
    std::lock_guard lock(mutex_);
    run("cannot store progress", "UPDATE jobs SET progress = ? WHERE id = ? AND state = 'running' AND node = ?",
        {protocol::to_json(p).dump(), id, node().name});
}

void PostgresJobStore::set_latest(const std::string& id, const std::string& output, const LatestFile& file) {
    std::lock_guard lock(mutex_);
    // One statement: the object's other outputs stay as they are.
    run("cannot store a job's newest file",
        "UPDATE jobs SET latest = CAST(CAST(latest AS JSONB) || jsonb_build_object(CAST(? AS TEXT), CAST(? AS JSONB)) "
        "AS TEXT) "
        "WHERE id = ? AND state = 'running' AND node = ?",
        {output, protocol::to_json(file).dump(), id, node().name});
}

bool PostgresJobStore::requeue(const std::string& id, const JobEvent& event, bool refund_attempt) {
    std::lock_guard lock(mutex_);
    Transaction t(*this);
    const Result r = run("cannot requeue a job",
                         "UPDATE jobs SET state = 'queued', attempts = attempts - ?, lease_expires = 0 "
                         "WHERE id = ? AND state = 'running' AND node = ?",
                         {refund_attempt ? "1" : "0", id, node().name});
    if (r.affected() == 0) return false;
    insert_event_locked(id, event);
    t.commit();
    return true;
}

bool PostgresJobStore::finish(const std::string& id, JobState state, const std::string& error, const std::string& cause,
                              const JobEvent& event) {
    std::lock_guard lock(mutex_);
    Transaction t(*this);
    const Result r = run("cannot finish a job",
                         "UPDATE jobs SET state = ?, error = ?, cause = ?, finished_at = ?, lease_expires = 0 "
                         "WHERE id = ? AND state IN ('queued', 'running')",
                         {to_string(state), error, cause, number(now_seconds()), id});
    if (r.affected() == 0) return false;
    insert_event_locked(id, event);
    t.commit();
    return true;
}

std::vector<JobRecord> PostgresJobStore::running_jobs() {
    std::lock_guard lock(mutex_);
    return select_jobs("cannot list running jobs", "WHERE state = 'running' ORDER BY seq", {});
}

bool PostgresJobStore::empty() {
    std::lock_guard lock(mutex_);
    return run("cannot count jobs and scenes", "SELECT (SELECT COUNT(*) FROM jobs) + (SELECT COUNT(*) FROM scenes)")
               .integer(0, 0) == 0;
}

bool PostgresJobStore::has_job(const std::string& id) {
    std::lock_guard lock(mutex_);
    return run("cannot read a job", "SELECT 1 FROM jobs WHERE id = ?", {id}).rows() > 0;
}

int64_t PostgresJobStore::compact_events(double finished_before) {
    std::lock_guard lock(mutex_);
    return run("cannot compact events",
               "DELETE FROM events WHERE coalesce_key IS NOT NULL AND job IN "
               "(SELECT id FROM jobs WHERE state IN ('succeeded', 'failed', 'cancelled') AND finished_at < ?) "
               "AND id < (SELECT MAX(e.id) FROM events e WHERE e.job = events.job "
               "AND e.coalesce_key = events.coalesce_key)",
               {number(finished_before)})
        .affected();
}

int64_t PostgresJobStore::append_event(const std::string& id, const JobEvent& event) {
    std::lock_guard lock(mutex_);
    Transaction t(*this);
    // The job's row lock orders this event after every other of the job.
    if (run("cannot lock a job", "SELECT 1 FROM jobs WHERE id = ? AND state = 'running' AND node = ? FOR UPDATE",
            {id, node().name})
            .rows() == 0)
        return 0;
    const int64_t event_id = insert_event_locked(id, event);
    t.commit();
    return event_id;
}

std::vector<JobEvent> PostgresJobStore::events_after(const std::string& id, int64_t after) {
    std::lock_guard lock(mutex_);
    const Result r = run("cannot read events", "SELECT id, type, data FROM events WHERE job = ? AND id > ? ORDER BY id",
                         {id, std::to_string(after)});
    std::vector<JobEvent> events;
    for (int i = 0; i < r.rows(); ++i)
        events.push_back(JobEvent{r.integer(i, 0), r.text(i, 1), json::parse(r.text(i, 2), nullptr, false)});
    return events;
}

void PostgresJobStore::heartbeat(const json& info) {
    std::lock_guard lock(mutex_);
    run("cannot store the node's heartbeat",
        std::string("INSERT INTO nodes(name, started_at, heartbeat_at, info) VALUES(?, ") + kDbNow + ", " + kDbNow +
            ", ?) ON CONFLICT(name) DO UPDATE SET heartbeat_at = excluded.heartbeat_at, info = excluded.info",
        {node().name, info.dump()});
}

std::vector<NodeRecord> PostgresJobStore::nodes() {
    std::lock_guard lock(mutex_);
    const Result r = run("cannot list nodes", std::string("SELECT name, started_at, heartbeat_at, ") + kDbNow +
                                                  " - heartbeat_at, info FROM nodes ORDER BY name");
    std::vector<NodeRecord> nodes;
    for (int i = 0; i < r.rows(); ++i)
        nodes.push_back(
            {r.text(i, 0), r.real(i, 1), r.real(i, 2), r.real(i, 3), json::parse(r.text(i, 4), nullptr, false)});
    return nodes;
}

}  // namespace lf::server
