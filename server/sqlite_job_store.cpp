#include "sqlite_job_store.h"

#include <sqlite3.h>

#include <chrono>
#include <stdexcept>

namespace lf::server {

using nlohmann::json;
using protocol::parse_job_state;
using protocol::to_string;

namespace {
double now_seconds() {
    return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

constexpr const char* kSchema = R"sql(
CREATE TABLE IF NOT EXISTS scenes(
  id TEXT PRIMARY KEY, main_file TEXT NOT NULL, summary TEXT NOT NULL, created_at REAL NOT NULL);
CREATE TABLE IF NOT EXISTS scene_owners(
  scene TEXT NOT NULL, owner TEXT NOT NULL, PRIMARY KEY(scene, owner));
CREATE TABLE IF NOT EXISTS jobs(
  seq INTEGER PRIMARY KEY AUTOINCREMENT,
  id TEXT UNIQUE NOT NULL, owner TEXT NOT NULL, scene TEXT NOT NULL, spec TEXT NOT NULL,
  state TEXT NOT NULL, progress TEXT NOT NULL, attempts INTEGER NOT NULL, max_attempts INTEGER NOT NULL,
  max_seconds REAL NOT NULL, error TEXT NOT NULL, cause TEXT NOT NULL, cache_key TEXT NOT NULL,
  cached INTEGER NOT NULL, created_at REAL NOT NULL, started_at REAL NOT NULL, finished_at REAL NOT NULL,
  latest TEXT NOT NULL DEFAULT '{}');
CREATE INDEX IF NOT EXISTS jobs_by_owner ON jobs(owner, seq);
CREATE INDEX IF NOT EXISTS jobs_by_state ON jobs(state, seq);
CREATE INDEX IF NOT EXISTS jobs_by_key ON jobs(cache_key, state);
CREATE TABLE IF NOT EXISTS events(
  job TEXT NOT NULL, id INTEGER NOT NULL, type TEXT NOT NULL, data TEXT NOT NULL, PRIMARY KEY(job, id));
)sql";

constexpr const char* kJobColumns =
    "id, owner, scene, spec, state, progress, attempts, max_attempts, max_seconds, error, cause, "
    "cache_key, cached, created_at, started_at, finished_at, latest";
}  // namespace

// A prepared statement: bind with `bind(...)`, then step() row by row.
class SqliteJobStore::Statement {
public:
    Statement(sqlite3* db, const std::string& sql) : db_(db) {
        if (sqlite3_prepare_v2(db, sql.c_str(), -1, &stmt_, nullptr) != SQLITE_OK)
            throw std::runtime_error(std::string("job store: ") + sqlite3_errmsg(db) + " in: " + sql);
    }
    ~Statement() { sqlite3_finalize(stmt_); }
    Statement& bind(int i, const std::string& v) {
        sqlite3_bind_text(stmt_, i, v.c_str(), int(v.size()), SQLITE_TRANSIENT);
        return *this;
    }
    Statement& bind(int i, int64_t v) {
        sqlite3_bind_int64(stmt_, i, v);
        return *this;
    }
    Statement& bind(int i, int v) { return bind(i, int64_t(v)); }
    Statement& bind(int i, double v) {
        sqlite3_bind_double(stmt_, i, v);
        return *this;
    }
    // True while there is a row; throws on errors.
    bool step() {
        const int rc = sqlite3_step(stmt_);
        if (rc == SQLITE_ROW) return true;
        if (rc == SQLITE_DONE) return false;
        throw std::runtime_error(std::string("job store: ") + sqlite3_errmsg(db_));
    }
    std::string text(int i) const {
        const auto* p = sqlite3_column_text(stmt_, i);
        return p ? std::string(reinterpret_cast<const char*>(p), size_t(sqlite3_column_bytes(stmt_, i))) : "";
    }
    int64_t integer(int i) const { return sqlite3_column_int64(stmt_, i); }
    double real(int i) const { return sqlite3_column_double(stmt_, i); }
    int changes() const { return sqlite3_changes(db_); }

private:
    sqlite3* db_;
    sqlite3_stmt* stmt_ = nullptr;
};

namespace {
// Commits at the end of scope unless an exception is flying.
class Transaction {
public:
    explicit Transaction(sqlite3* db) : db_(db) { run("BEGIN IMMEDIATE"); }
    ~Transaction() { run(std::uncaught_exceptions() ? "ROLLBACK" : "COMMIT"); }

private:
    void run(const char* sql) { sqlite3_exec(db_, sql, nullptr, nullptr, nullptr); }
    sqlite3* db_;
};
}  // namespace

SqliteJobStore::SqliteJobStore(const std::string& path) : path_(path) {
    if (sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_FULLMUTEX,
                        nullptr) != SQLITE_OK) {
        const std::string why = db_ ? sqlite3_errmsg(db_) : "out of memory";
        sqlite3_close(db_);
        throw std::runtime_error("cannot open job store " + path + ": " + why);
    }
    sqlite3_busy_timeout(db_, 5000);
    // WAL + NORMAL: a killed lightfarmd loses nothing committed (only a power
    // loss could lose the last transactions).
    exec("PRAGMA journal_mode=WAL");
    exec("PRAGMA synchronous=NORMAL");
    exec(kSchema);
    // A store created before jobs had `latest` (the newest file per output).
    bool has_latest = false;
    {
        Statement columns(db_, "PRAGMA table_info(jobs)");
        while (columns.step()) has_latest = has_latest || columns.text(1) == "latest";
    }
    if (!has_latest) exec("ALTER TABLE jobs ADD COLUMN latest TEXT NOT NULL DEFAULT '{}'");
}

SqliteJobStore::~SqliteJobStore() { sqlite3_close(db_); }

void SqliteJobStore::exec(const char* sql) {
    char* message = nullptr;
    if (sqlite3_exec(db_, sql, nullptr, nullptr, &message) != SQLITE_OK) {
        const std::string why = message ? message : "unknown error";
        sqlite3_free(message);
        throw std::runtime_error("job store " + path_ + ": " + why);
    }
}

std::optional<SceneRecord> SqliteJobStore::scene(const std::string& id) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "SELECT id, main_file, summary FROM scenes WHERE id = ?");
    q.bind(1, id);
    if (!q.step()) return std::nullopt;
    return SceneRecord{q.text(0), q.text(1), json::parse(q.text(2), nullptr, false)};
}

void SqliteJobStore::add_scene(const SceneRecord& scene) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "INSERT OR IGNORE INTO scenes(id, main_file, summary, created_at) VALUES(?, ?, ?, ?)");
    q.bind(1, scene.id).bind(2, scene.main_file).bind(3, scene.summary.dump()).bind(4, now_seconds());
    q.step();
}

bool SqliteJobStore::add_scene_owner(const std::string& id, const std::string& owner) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "INSERT OR IGNORE INTO scene_owners(scene, owner) VALUES(?, ?)");
    q.bind(1, id).bind(2, owner);
    q.step();
    return q.changes() > 0;
}

bool SqliteJobStore::scene_owned_by(const std::string& id, const std::string& owner) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "SELECT 1 FROM scene_owners WHERE scene = ? AND owner = ?");
    q.bind(1, id).bind(2, owner);
    return q.step();
}

int64_t SqliteJobStore::insert_event_locked(const std::string& id, const JobEvent& event) {
    Statement next(db_, "SELECT COALESCE(MAX(id), 0) + 1 FROM events WHERE job = ?");
    next.bind(1, id);
    next.step();
    const int64_t event_id = next.integer(0);
    Statement q(db_, "INSERT INTO events(job, id, type, data) VALUES(?, ?, ?, ?)");
    q.bind(1, id).bind(2, event_id).bind(3, event.type).bind(4, event.data.dump());
    q.step();
    return event_id;
}

void SqliteJobStore::insert_job(const JobRecord& job, const std::vector<JobEvent>& events) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    const JobStatus& s = job.status;
    Statement q(db_, std::string("INSERT INTO jobs(") + kJobColumns +
                         ") VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
    q.bind(1, s.id).bind(2, job.owner).bind(3, s.scene).bind(4, s.spec.dump()).bind(5, to_string(s.state));
    q.bind(6, protocol::to_json(s.progress).dump()).bind(7, s.attempts).bind(8, s.max_attempts);
    q.bind(9, job.max_seconds).bind(10, s.error).bind(11, s.cause).bind(12, job.cache_key);
    q.bind(13, int(s.cached)).bind(14, s.created_at > 0 ? s.created_at : now_seconds());
    q.bind(15, s.started_at).bind(16, s.finished_at).bind(17, protocol::to_json(s.latest).dump());
    q.step();
    for (const JobEvent& e : events) insert_event_locked(s.id, e);
}

std::vector<JobRecord> SqliteJobStore::select_jobs(const std::string& where, const std::vector<std::string>& args) {
    Statement q(db_, std::string("SELECT ") + kJobColumns + " FROM jobs " + where);
    for (size_t i = 0; i < args.size(); ++i) q.bind(int(i + 1), args[i]);
    std::vector<JobRecord> jobs;
    while (q.step()) {
        JobRecord r;
        JobStatus& s = r.status;
        s.id = q.text(0);
        r.owner = q.text(1);
        s.scene = q.text(2);
        s.spec = json::parse(q.text(3), nullptr, false);
        s.state = parse_job_state(q.text(4)).value_or(JobState::Failed);
        s.progress = protocol::progress_from_json(json::parse(q.text(5), nullptr, false));
        s.attempts = int(q.integer(6));
        s.max_attempts = int(q.integer(7));
        r.max_seconds = q.real(8);
        s.error = q.text(9);
        s.cause = q.text(10);
        r.cache_key = q.text(11);
        s.cached = q.integer(12) != 0;
        s.created_at = q.real(13);
        s.started_at = q.real(14);
        s.finished_at = q.real(15);
        s.latest = protocol::latest_from_json(json::parse(q.text(16), nullptr, false));
        jobs.push_back(std::move(r));
    }
    return jobs;
}

std::optional<JobRecord> SqliteJobStore::job(const std::string& id) {
    std::lock_guard lock(mutex_);
    auto jobs = select_jobs("WHERE id = ?", {id});
    if (jobs.empty()) return std::nullopt;
    return jobs.front();
}

std::vector<JobRecord> SqliteJobStore::jobs_of(const std::string& owner) {
    std::lock_guard lock(mutex_);
    return select_jobs("WHERE owner = ? ORDER BY seq DESC", {owner});
}

int SqliteJobStore::queued_count(const std::string& owner) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "SELECT COUNT(*) FROM jobs WHERE owner = ? AND state = 'queued'");
    q.bind(1, owner);
    q.step();
    return int(q.integer(0));
}

std::map<JobState, int> SqliteJobStore::count_by_state() {
    std::lock_guard lock(mutex_);
    std::map<JobState, int> counts;
    Statement q(db_, "SELECT state, COUNT(*) FROM jobs GROUP BY state");
    while (q.step())
        if (auto st = parse_job_state(q.text(0))) counts[*st] = int(q.integer(1));
    return counts;
}

std::optional<JobRecord> SqliteJobStore::succeeded_with_key(const std::string& cache_key) {
    std::lock_guard lock(mutex_);
    auto jobs = select_jobs("WHERE cache_key = ? AND state = 'succeeded' AND cached = 0 ORDER BY seq LIMIT 1", {cache_key});
    if (jobs.empty()) return std::nullopt;
    return jobs.front();
}

std::optional<JobRecord> SqliteJobStore::claim_next() {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    auto jobs = select_jobs("WHERE state = 'queued' ORDER BY seq LIMIT 1", {});
    if (jobs.empty()) return std::nullopt;
    JobRecord job = jobs.front();
    job.status.state = JobState::Running;
    job.status.attempts += 1;
    job.status.started_at = now_seconds();
    job.status.progress = Progress{};
    Statement q(db_, "UPDATE jobs SET state = 'running', attempts = ?, started_at = ?, progress = ? WHERE id = ?");
    q.bind(1, job.status.attempts).bind(2, job.status.started_at);
    q.bind(3, protocol::to_json(job.status.progress).dump()).bind(4, job.status.id);
    q.step();
    return job;
}

void SqliteJobStore::set_progress(const std::string& id, const Progress& p) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "UPDATE jobs SET progress = ? WHERE id = ? AND state = 'running'");
    q.bind(1, protocol::to_json(p).dump()).bind(2, id);
    q.step();
}

void SqliteJobStore::set_latest(const std::string& id, const std::string& output, const LatestFile& file) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    Statement read(db_, "SELECT latest FROM jobs WHERE id = ? AND state = 'running'");
    read.bind(1, id);
    if (!read.step()) return;
    json latest = json::parse(read.text(0), nullptr, false);
    if (!latest.is_object()) latest = json::object();
    latest[output] = protocol::to_json(file);
    Statement q(db_, "UPDATE jobs SET latest = ? WHERE id = ?");
    q.bind(1, latest.dump()).bind(2, id);
    q.step();
}

bool SqliteJobStore::requeue(const std::string& id, const JobEvent& event, bool refund_attempt) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    Statement q(db_, "UPDATE jobs SET state = 'queued', attempts = attempts - ? WHERE id = ? AND state = 'running'");
    q.bind(1, refund_attempt ? 1 : 0).bind(2, id);
    q.step();
    if (q.changes() == 0) return false;
    insert_event_locked(id, event);
    return true;
}

bool SqliteJobStore::finish(const std::string& id, JobState state, const std::string& error,
                            const std::string& cause, const JobEvent& event) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    Statement q(db_, "UPDATE jobs SET state = ?, error = ?, cause = ?, finished_at = ? "
                     "WHERE id = ? AND state IN ('queued', 'running')");
    q.bind(1, to_string(state)).bind(2, error).bind(3, cause).bind(4, now_seconds()).bind(5, id);
    q.step();
    if (q.changes() == 0) return false;
    insert_event_locked(id, event);
    return true;
}

std::vector<JobRecord> SqliteJobStore::running_jobs() {
    std::lock_guard lock(mutex_);
    return select_jobs("WHERE state = 'running' ORDER BY seq", {});
}

int64_t SqliteJobStore::append_event(const std::string& id, const JobEvent& event) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    Statement check(db_, "SELECT 1 FROM jobs WHERE id = ? AND state = 'running'");
    check.bind(1, id);
    if (!check.step()) return 0;
    return insert_event_locked(id, event);
}

std::vector<JobEvent> SqliteJobStore::events_after(const std::string& id, int64_t after) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "SELECT id, type, data FROM events WHERE job = ? AND id > ? ORDER BY id");
    q.bind(1, id).bind(2, after);
    std::vector<JobEvent> events;
    while (q.step()) events.push_back(JobEvent{q.integer(0), q.text(1), json::parse(q.text(2), nullptr, false)});
    return events;
}

}  // namespace lf::server
