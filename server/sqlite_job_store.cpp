#include "sqlite_job_store.h"

#include <sqlite3.h>
#include <sys/stat.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <mutex>
#include <stdexcept>

namespace lf::server {

using nlohmann::json;
using protocol::parse_job_state;
using protocol::to_string;

namespace {
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
  latest TEXT NOT NULL DEFAULT '{}', node TEXT NOT NULL DEFAULT '', lease_expires REAL NOT NULL DEFAULT 0);
CREATE INDEX IF NOT EXISTS jobs_by_owner ON jobs(owner, seq);
CREATE INDEX IF NOT EXISTS jobs_by_state ON jobs(state, seq);
CREATE INDEX IF NOT EXISTS jobs_by_key ON jobs(cache_key, state);
CREATE TABLE IF NOT EXISTS events(
  job TEXT NOT NULL, id INTEGER NOT NULL, type TEXT NOT NULL, data TEXT NOT NULL,
  coalesce_key TEXT, permanent INTEGER NOT NULL DEFAULT 1, PRIMARY KEY(job, id));
CREATE TABLE IF NOT EXISTS nodes(
  name TEXT PRIMARY KEY, started_at REAL NOT NULL, heartbeat_at REAL NOT NULL, info TEXT NOT NULL);
)sql";

[[noreturn]] void store_failed(sqlite3* db, const std::string& what) {
    throw StoreError("job store: " + what + ": " + sqlite3_errmsg(db));
}

// ---- the test hook: a VFS over the default one whose writes can fail -------
std::atomic<bool> g_full_disk{false};
sqlite3_vfs* g_real_vfs = nullptr;
sqlite3_vfs g_fault_vfs;
sqlite3_io_methods g_fault_io;

struct FaultFile {
    sqlite3_file base;
    sqlite3_file* real;
};
sqlite3_file* real_of(sqlite3_file* f) { return reinterpret_cast<FaultFile*>(f)->real; }

int fault_close(sqlite3_file* f) { return real_of(f)->pMethods->xClose(real_of(f)); }
int fault_read(sqlite3_file* f, void* b, int n, sqlite3_int64 o) {
    return real_of(f)->pMethods->xRead(real_of(f), b, n, o);
}
int fault_write(sqlite3_file* f, const void* b, int n, sqlite3_int64 o) {
    if (g_full_disk) return SQLITE_FULL;
    return real_of(f)->pMethods->xWrite(real_of(f), b, n, o);
}
int fault_truncate(sqlite3_file* f, sqlite3_int64 n) { return real_of(f)->pMethods->xTruncate(real_of(f), n); }
int fault_sync(sqlite3_file* f, int flags) { return real_of(f)->pMethods->xSync(real_of(f), flags); }
int fault_size(sqlite3_file* f, sqlite3_int64* n) { return real_of(f)->pMethods->xFileSize(real_of(f), n); }
int fault_lock(sqlite3_file* f, int l) { return real_of(f)->pMethods->xLock(real_of(f), l); }
int fault_unlock(sqlite3_file* f, int l) { return real_of(f)->pMethods->xUnlock(real_of(f), l); }
int fault_reserved(sqlite3_file* f, int* r) { return real_of(f)->pMethods->xCheckReservedLock(real_of(f), r); }
int fault_control(sqlite3_file* f, int op, void* a) { return real_of(f)->pMethods->xFileControl(real_of(f), op, a); }
int fault_sector(sqlite3_file* f) { return real_of(f)->pMethods->xSectorSize(real_of(f)); }
int fault_characteristics(sqlite3_file* f) { return real_of(f)->pMethods->xDeviceCharacteristics(real_of(f)); }
int fault_shm_map(sqlite3_file* f, int pg, int sz, int ext, void volatile** p) {
    return real_of(f)->pMethods->xShmMap(real_of(f), pg, sz, ext, p);
}
int fault_shm_lock(sqlite3_file* f, int off, int n, int flags) {
    return real_of(f)->pMethods->xShmLock(real_of(f), off, n, flags);
}
void fault_shm_barrier(sqlite3_file* f) { real_of(f)->pMethods->xShmBarrier(real_of(f)); }
int fault_shm_unmap(sqlite3_file* f, int del) { return real_of(f)->pMethods->xShmUnmap(real_of(f), del); }
int fault_fetch(sqlite3_file* f, sqlite3_int64 o, int n, void** p) {
    return real_of(f)->pMethods->xFetch(real_of(f), o, n, p);
}
int fault_unfetch(sqlite3_file* f, sqlite3_int64 o, void* p) {
    return real_of(f)->pMethods->xUnfetch(real_of(f), o, p);
}

int fault_open(sqlite3_vfs*, sqlite3_filename name, sqlite3_file* f, int flags, int* out_flags) {
    auto* ff = reinterpret_cast<FaultFile*>(f);
    ff->real = reinterpret_cast<sqlite3_file*>(reinterpret_cast<char*>(f) + sizeof(FaultFile));
    const int rc = g_real_vfs->xOpen(g_real_vfs, name, ff->real, flags, out_flags);
    // Methods of our own exactly when the real file has some (SQLite then closes it).
    f->pMethods = ff->real->pMethods ? &g_fault_io : nullptr;
    return rc;
}
int fault_delete(sqlite3_vfs*, const char* n, int sync) { return g_real_vfs->xDelete(g_real_vfs, n, sync); }
int fault_access(sqlite3_vfs*, const char* n, int flags, int* out) {
    return g_real_vfs->xAccess(g_real_vfs, n, flags, out);
}
int fault_full_path(sqlite3_vfs*, const char* n, int size, char* out) {
    return g_real_vfs->xFullPathname(g_real_vfs, n, size, out);
}
void* fault_dlopen(sqlite3_vfs*, const char* n) { return g_real_vfs->xDlOpen(g_real_vfs, n); }
void fault_dlerror(sqlite3_vfs*, int n, char* out) { g_real_vfs->xDlError(g_real_vfs, n, out); }
void (*fault_dlsym(sqlite3_vfs*, void* h, const char* s))(void) { return g_real_vfs->xDlSym(g_real_vfs, h, s); }
void fault_dlclose(sqlite3_vfs*, void* h) { g_real_vfs->xDlClose(g_real_vfs, h); }
int fault_random(sqlite3_vfs*, int n, char* out) { return g_real_vfs->xRandomness(g_real_vfs, n, out); }
int fault_sleep(sqlite3_vfs*, int us) { return g_real_vfs->xSleep(g_real_vfs, us); }
int fault_time(sqlite3_vfs*, double* t) { return g_real_vfs->xCurrentTime(g_real_vfs, t); }
int fault_last_error(sqlite3_vfs*, int n, char* out) { return g_real_vfs->xGetLastError(g_real_vfs, n, out); }
int fault_time64(sqlite3_vfs*, sqlite3_int64* t) { return g_real_vfs->xCurrentTimeInt64(g_real_vfs, t); }

void install_fault_vfs() {
    sqlite3_initialize();
    g_real_vfs = sqlite3_vfs_find(nullptr);
    if (!g_real_vfs || g_real_vfs->iVersion < 2) throw std::runtime_error("no default SQLite VFS to wrap");
    g_fault_io = sqlite3_io_methods{};
    g_fault_io.iVersion = 3;
    g_fault_io.xClose = fault_close;
    g_fault_io.xRead = fault_read;
    g_fault_io.xWrite = fault_write;
    g_fault_io.xTruncate = fault_truncate;
    g_fault_io.xSync = fault_sync;
    g_fault_io.xFileSize = fault_size;
    g_fault_io.xLock = fault_lock;
    g_fault_io.xUnlock = fault_unlock;
    g_fault_io.xCheckReservedLock = fault_reserved;
    g_fault_io.xFileControl = fault_control;
    g_fault_io.xSectorSize = fault_sector;
    g_fault_io.xDeviceCharacteristics = fault_characteristics;
    g_fault_io.xShmMap = fault_shm_map;
    g_fault_io.xShmLock = fault_shm_lock;
    g_fault_io.xShmBarrier = fault_shm_barrier;
    g_fault_io.xShmUnmap = fault_shm_unmap;
    g_fault_io.xFetch = fault_fetch;
    g_fault_io.xUnfetch = fault_unfetch;
    g_fault_vfs = sqlite3_vfs{};
    g_fault_vfs.iVersion = 2;
    g_fault_vfs.szOsFile = int(sizeof(FaultFile)) + g_real_vfs->szOsFile;
    g_fault_vfs.mxPathname = g_real_vfs->mxPathname;
    g_fault_vfs.zName = "lightfarm-test-full-disk";
    g_fault_vfs.xOpen = fault_open;
    g_fault_vfs.xDelete = fault_delete;
    g_fault_vfs.xAccess = fault_access;
    g_fault_vfs.xFullPathname = fault_full_path;
    g_fault_vfs.xDlOpen = fault_dlopen;
    g_fault_vfs.xDlError = fault_dlerror;
    g_fault_vfs.xDlSym = fault_dlsym;
    g_fault_vfs.xDlClose = fault_dlclose;
    g_fault_vfs.xRandomness = fault_random;
    g_fault_vfs.xSleep = fault_sleep;
    g_fault_vfs.xCurrentTime = fault_time;
    g_fault_vfs.xGetLastError = fault_last_error;
    g_fault_vfs.xCurrentTimeInt64 = fault_time64;
    if (sqlite3_vfs_register(&g_fault_vfs, 1) != SQLITE_OK) throw std::runtime_error("cannot register the test VFS");
}
}  // namespace

// A prepared statement: bind with `bind(...)`, then step() row by row.
class SqliteJobStore::Statement {
public:
    Statement(sqlite3* db, const std::string& sql) : db_(db) {
        if (sqlite3_prepare_v2(db, sql.c_str(), -1, &stmt_, nullptr) != SQLITE_OK)
            store_failed(db, "cannot prepare '" + sql.substr(0, 60) + "'");
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
    // True while there is a row; throws StoreError on errors (in autocommit
    // mode a write's commit is part of its step: its failure lands here).
    bool step() {
        const int rc = sqlite3_step(stmt_);
        if (rc == SQLITE_ROW) return true;
        if (rc == SQLITE_DONE) return false;
        store_failed(db_, sqlite3_stmt_readonly(stmt_) ? "read failed" : "write failed");
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
// A write transaction: commit() stores it (and throws StoreError when the
// COMMIT fails: then nothing of it is stored); leaving the scope without
// commit() rolls it back.
class Transaction {
public:
    explicit Transaction(sqlite3* db) : db_(db) {
        if (sqlite3_exec(db_, "BEGIN IMMEDIATE", nullptr, nullptr, nullptr) != SQLITE_OK)
            store_failed(db_, "cannot begin a transaction");
    }
    ~Transaction() {
        if (!done_) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
    }
    Transaction(const Transaction&) = delete;
    Transaction& operator=(const Transaction&) = delete;
    void commit() {
        if (sqlite3_exec(db_, "COMMIT", nullptr, nullptr, nullptr) != SQLITE_OK) {
            const std::string why = sqlite3_errmsg(db_);
            // A failed COMMIT may leave the transaction open: end it, so
            // the next call starts clean, and say what failed.
            if (sqlite3_get_autocommit(db_) == 0) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
            done_ = true;
            throw StoreError("job store: commit failed: " + why);
        }
        done_ = true;
    }

private:
    sqlite3* db_;
    bool done_ = false;
};
}  // namespace

void SqliteJobStore::simulate_full_disk_for_tests(bool fail) {
    static std::once_flag installed;
    std::call_once(installed, install_fault_vfs);
    g_full_disk = fail;
}

SqliteJobStore::SqliteJobStore(const std::string& path, NodeIdentity node) : JobStore(std::move(node)), path_(path) {
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
    // A store created before leases (scale-out): its running jobs are taken
    // over at start like any other (take_over_abandoned).
    bool has_node = false;
    {
        Statement columns(db_, "PRAGMA table_info(jobs)");
        while (columns.step()) has_node = has_node || columns.text(1) == "node";
    }
    if (!has_node) {
        exec("ALTER TABLE jobs ADD COLUMN node TEXT NOT NULL DEFAULT ''");
        exec("ALTER TABLE jobs ADD COLUMN lease_expires REAL NOT NULL DEFAULT 0");
    }
    // A store created before progress events were coalesced: its progress
    // rows are kept (permanent) until compact_events() reaches their jobs.
    bool has_coalesce = false;
    {
        Statement columns(db_, "PRAGMA table_info(events)");
        while (columns.step()) has_coalesce = has_coalesce || columns.text(1) == "coalesce_key";
    }
    if (!has_coalesce) {
        exec("ALTER TABLE events ADD COLUMN coalesce_key TEXT");
        exec("ALTER TABLE events ADD COLUMN permanent INTEGER NOT NULL DEFAULT 1");
        if (sqlite3_exec(db_,
                         "UPDATE events SET coalesce_key = COALESCE(json_extract(data, '$.output'), '') "
                         "WHERE type = 'progress'",
                         nullptr, nullptr, nullptr) != SQLITE_OK)
            exec("UPDATE events SET coalesce_key = '' WHERE type = 'progress'");
    }
    // Readable by lightfarmd's user only (-wal and -shm take the same mode).
    struct stat st {};
    if (::stat(path.c_str(), &st) == 0 && S_ISREG(st.st_mode) && (st.st_mode & 0077)) ::chmod(path.c_str(), 0600);
}

SqliteJobStore::~SqliteJobStore() { sqlite3_close(db_); }

void SqliteJobStore::exec(const char* sql) {
    char* message = nullptr;
    if (sqlite3_exec(db_, sql, nullptr, nullptr, &message) != SQLITE_OK) {
        const std::string why = message ? message : "unknown error";
        sqlite3_free(message);
        throw StoreError("job store " + path_ + ": " + why);
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
    // The id first: the event a progress event replaces may be the newest,
    // and an id is never given twice.
    Statement next(db_, "SELECT COALESCE(MAX(id), 0) + 1 FROM events WHERE job = ?");
    next.bind(1, id);
    next.step();
    const int64_t event_id = next.integer(0);
    const bool progress = event.type == "progress";
    std::string key;
    bool permanent = true;
    if (progress) {
        key = progress_key(event);
        permanent = permanent_progress(event.data);
        Statement replace(db_, "DELETE FROM events WHERE job = ? AND coalesce_key = ? AND permanent = 0");
        replace.bind(1, id).bind(2, key);
        replace.step();
    }
    Statement q(db_, "INSERT INTO events(job, id, type, data, coalesce_key, permanent) VALUES(?, ?, ?, ?, ?, ?)");
    q.bind(1, id).bind(2, event_id).bind(3, event.type).bind(4, event.data.dump());
    if (progress) q.bind(5, key);  // else NULL
    q.bind(6, int(permanent));
    q.step();
    return event_id;
}

void SqliteJobStore::insert_job(const JobRecord& job, const std::vector<JobEvent>& events) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    const JobStatus& s = job.status;
    Statement q(db_, std::string("INSERT INTO jobs(") + kJobColumns +
                         ", lease_expires) VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
    q.bind(1, s.id).bind(2, job.owner).bind(3, s.scene).bind(4, s.spec.dump()).bind(5, to_string(s.state));
    q.bind(6, protocol::to_json(s.progress).dump()).bind(7, s.attempts).bind(8, s.max_attempts);
    q.bind(9, job.max_seconds).bind(10, s.error).bind(11, s.cause).bind(12, job.cache_key);
    q.bind(13, int(s.cached)).bind(14, s.created_at > 0 ? s.created_at : now_seconds());
    q.bind(15, s.started_at).bind(16, s.finished_at).bind(17, protocol::to_json(s.latest).dump());
    // A job born running (tests, imports) runs on this node.
    const bool running = s.state == JobState::Running;
    q.bind(18, running ? node().name : job.node).bind(19, running ? now_seconds() + node().lease_seconds : 0.0);
    q.step();
    for (const JobEvent& e : events) insert_event_locked(s.id, e);
    t.commit();
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
        r.node = q.text(17);
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
    auto jobs =
        select_jobs("WHERE cache_key = ? AND state = 'succeeded' AND cached = 0 ORDER BY seq LIMIT 1", {cache_key});
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
    job.node = node().name;
    Statement q(db_,
                "UPDATE jobs SET state = 'running', attempts = ?, started_at = ?, progress = ?, node = ?, "
                "lease_expires = ? WHERE id = ?");
    q.bind(1, job.status.attempts).bind(2, job.status.started_at);
    q.bind(3, protocol::to_json(job.status.progress).dump()).bind(4, job.node);
    q.bind(5, job.status.started_at + node().lease_seconds).bind(6, job.status.id);
    q.step();
    t.commit();
    return job;
}

bool SqliteJobStore::renew_lease(const std::string& id) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "UPDATE jobs SET lease_expires = ? WHERE id = ? AND state = 'running' AND node = ?");
    q.bind(1, now_seconds() + node().lease_seconds).bind(2, id).bind(3, node().name);
    q.step();
    return q.changes() > 0;
}

std::vector<JobRecord> SqliteJobStore::take_over_abandoned(bool at_start) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    // One lightfarmd per SQLite file (the data directory's lock): at start,
    // every running job was left by a previous lightfarmd; later, a job of
    // another node (a store copied from elsewhere) only once its lease expired.
    const double now = now_seconds();
    auto jobs = at_start ? select_jobs("WHERE state = 'running' ORDER BY seq", {})
                         : select_jobs("WHERE state = 'running' AND node <> ? AND lease_expires < " +
                                           std::to_string(now) + " ORDER BY seq",
                                       {node().name});
    for (const JobRecord& job : jobs) {
        Statement q(db_, "UPDATE jobs SET node = ?, lease_expires = ? WHERE id = ?");
        q.bind(1, node().name).bind(2, now + node().lease_seconds).bind(3, job.status.id);
        q.step();
    }
    t.commit();
    return jobs;
}

void SqliteJobStore::set_progress(const std::string& id, const Progress& p) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "UPDATE jobs SET progress = ? WHERE id = ? AND state = 'running' AND node = ?");
    q.bind(1, protocol::to_json(p).dump()).bind(2, id).bind(3, node().name);
    q.step();
}

void SqliteJobStore::set_latest(const std::string& id, const std::string& output, const LatestFile& file) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    Statement read(db_, "SELECT latest FROM jobs WHERE id = ? AND state = 'running' AND node = ?");
    read.bind(1, id).bind(2, node().name);
    if (!read.step()) return;
    json latest = json::parse(read.text(0), nullptr, false);
    if (!latest.is_object()) latest = json::object();
    latest[output] = protocol::to_json(file);
    Statement q(db_, "UPDATE jobs SET latest = ? WHERE id = ?");
    q.bind(1, latest.dump()).bind(2, id);
    q.step();
    t.commit();
}

bool SqliteJobStore::requeue(const std::string& id, const JobEvent& event, bool refund_attempt) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    Statement q(db_,
                "UPDATE jobs SET state = 'queued', attempts = attempts - ?, lease_expires = 0 "
                "WHERE id = ? AND state = 'running' AND node = ?");
    q.bind(1, refund_attempt ? 1 : 0).bind(2, id).bind(3, node().name);
    q.step();
    if (q.changes() == 0) return false;
    insert_event_locked(id, event);
    t.commit();
    return true;
}

bool SqliteJobStore::finish(const std::string& id, JobState state, const std::string& error, const std::string& cause,
                            const JobEvent& event) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    Statement q(db_,
                "UPDATE jobs SET state = ?, error = ?, cause = ?, finished_at = ? "
                "WHERE id = ? AND state IN ('queued', 'running')");
    q.bind(1, to_string(state)).bind(2, error).bind(3, cause).bind(4, now_seconds()).bind(5, id);
    q.step();
    if (q.changes() == 0) return false;
    insert_event_locked(id, event);
    t.commit();
    return true;
}

std::vector<JobRecord> SqliteJobStore::running_jobs() {
    std::lock_guard lock(mutex_);
    return select_jobs("WHERE state = 'running' ORDER BY seq", {});
}

bool SqliteJobStore::empty() {
    std::lock_guard lock(mutex_);
    Statement q(db_, "SELECT (SELECT COUNT(*) FROM jobs) + (SELECT COUNT(*) FROM scenes)");
    q.step();
    return q.integer(0) == 0;
}

bool SqliteJobStore::has_job(const std::string& id) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "SELECT 1 FROM jobs WHERE id = ?");
    q.bind(1, id);
    return q.step();
}

int64_t SqliteJobStore::compact_events(double finished_before) {
    std::lock_guard lock(mutex_);
    Statement q(
        db_,
        "DELETE FROM events WHERE coalesce_key IS NOT NULL AND job IN "
        "(SELECT id FROM jobs WHERE state IN ('succeeded', 'failed', 'cancelled') AND finished_at < ?) "
        "AND id < (SELECT MAX(e.id) FROM events e WHERE e.job = events.job AND e.coalesce_key = events.coalesce_key)");
    q.bind(1, finished_before);
    q.step();
    return q.changes();
}

int64_t SqliteJobStore::append_event(const std::string& id, const JobEvent& event) {
    std::lock_guard lock(mutex_);
    Transaction t(db_);
    Statement check(db_, "SELECT 1 FROM jobs WHERE id = ? AND state = 'running' AND node = ?");
    check.bind(1, id).bind(2, node().name);
    if (!check.step()) return 0;
    const int64_t event_id = insert_event_locked(id, event);
    t.commit();
    return event_id;
}

std::vector<JobEvent> SqliteJobStore::events_after(const std::string& id, int64_t after) {
    std::lock_guard lock(mutex_);
    Statement q(db_, "SELECT id, type, data FROM events WHERE job = ? AND id > ? ORDER BY id");
    q.bind(1, id).bind(2, after);
    std::vector<JobEvent> events;
    while (q.step()) events.push_back(JobEvent{q.integer(0), q.text(1), json::parse(q.text(2), nullptr, false)});
    return events;
}

void SqliteJobStore::heartbeat(const json& info) {
    std::lock_guard lock(mutex_);
    const double now = now_seconds();
    Statement q(db_,
                "INSERT INTO nodes(name, started_at, heartbeat_at, info) VALUES(?, ?, ?, ?) "
                "ON CONFLICT(name) DO UPDATE SET heartbeat_at = excluded.heartbeat_at, info = excluded.info");
    q.bind(1, node().name).bind(2, now).bind(3, now).bind(4, info.dump());
    q.step();
}

std::vector<NodeRecord> SqliteJobStore::nodes() {
    std::lock_guard lock(mutex_);
    Statement q(db_, "SELECT name, started_at, heartbeat_at, info FROM nodes ORDER BY name");
    std::vector<NodeRecord> nodes;
    const double now = now_seconds();
    while (q.step())
        nodes.push_back({q.text(0), q.real(1), q.real(2), now - q.real(2), json::parse(q.text(3), nullptr, false)});
    return nodes;
}

}  // namespace lf::server
