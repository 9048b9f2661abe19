#include "sqlite_job_store.h"

#include <sqlite3.h>
#include <sys/stat.h>

#include <atomic>
#include <memory>
#include <mutex>
#include <stdexcept>

namespace lf::server {

namespace {
constexpr const char* kSchema = R"sql(
CREATE TABLE IF NOT EXISTS scenes(
  id TEXT PRIMARY KEY, main_file TEXT NOT NULL, summary TEXT NOT NULL, created_at REAL NOT NULL);
CREATE TABLE IF NOT EXISTS scene_owners(
  scene TEXT NOT NULL, owner TEXT NOT NULL, name TEXT NOT NULL DEFAULT '', PRIMARY KEY(scene, owner));
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
    throw StoreError("job store: " + what + ": " + sqlite3_errmsg(db), sqlite_store_cause(sqlite3_errcode(db)));
}

}  // namespace

std::string sqlite_store_cause(int code) {
    switch (code & 0xff) {  // the primary code of an extended one
    case SQLITE_FULL: return "its disk is full";
    case SQLITE_READONLY: return "it is read-only";
    case SQLITE_IOERR: return "its disk answered with an I/O error";
    case SQLITE_BUSY:
    case SQLITE_LOCKED: return "it is busy";
    case SQLITE_NOMEM: return "the server is out of memory";
    case SQLITE_CANTOPEN: return "it cannot be opened";
    default: return StoreError::kFailed;
    }
}

namespace {

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

// ---- the SQLite connection -----------------------------------------------
namespace {

// SQLite's `now` (the dialect's): the node's own clock, which is the
// database's (one lightfarmd per file), as fine as now_seconds()
// (julianday('now') counts whole milliseconds).
void sqlite_now(sqlite3_context* context, int, sqlite3_value**) { sqlite3_result_double(context, now_seconds()); }

constexpr SqlDialect kSqliteDialect = {
    .now = "lightfarm_now()",
    // A write transaction (BEGIN IMMEDIATE) locks the whole database: there
    // are no row locks to take, and no claim of another node to skip.
    .for_update = "",
    .for_update_skip_locked = "",
    // JSON is text; json_set's path names the key quoted ($."lightmap").
    .latest_with_key = "json_set(latest, '$.' || json_quote(?), json(?))",
    .writable_ctes = false,
    .shared = false,
};

class SqliteConnection : public SqlConnection {
public:
    // Opens (creates) the file and brings its schema up to date.
    explicit SqliteConnection(const std::string& path);
    ~SqliteConnection() override { sqlite3_close(db_); }
    SqliteConnection(const SqliteConnection&) = delete;
    SqliteConnection& operator=(const SqliteConnection&) = delete;

    const SqlDialect& dialect() const override { return kSqliteDialect; }
    SqlResult run(const char* what, const std::string& sql, const std::vector<SqlValue>& params) override;
    void begin() override;
    void commit() override;
    void rollback() noexcept override { sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr); }

private:
    void configure();
    void migrate();
    bool has_column(const char* table, const std::string& column);
    // Schema statements, several at once; a failure names the file.
    void exec(const char* sql);

    sqlite3* db_ = nullptr;
    std::string path_;
};

void bind(sqlite3_stmt* stmt, int i, const SqlValue& value) {
    if (const bool* b = std::get_if<bool>(&value)) sqlite3_bind_int64(stmt, i, *b ? 1 : 0);
    else if (const int64_t* n = std::get_if<int64_t>(&value)) sqlite3_bind_int64(stmt, i, *n);
    else if (const double* d = std::get_if<double>(&value)) sqlite3_bind_double(stmt, i, *d);
    else if (const std::string* s = std::get_if<std::string>(&value))
        sqlite3_bind_text(stmt, i, s->c_str(), int(s->size()), SQLITE_TRANSIENT);
    else sqlite3_bind_null(stmt, i);
}

// The current row, each column in the type SQLite stored it with (a real
// read as text would lose digits).
std::vector<SqlValue> row_of(sqlite3_stmt* stmt) {
    std::vector<SqlValue> row;
    for (int i = 0; i < sqlite3_column_count(stmt); ++i) {
        switch (sqlite3_column_type(stmt, i)) {
        case SQLITE_NULL: row.emplace_back(nullptr); break;
        case SQLITE_INTEGER: row.emplace_back(int64_t(sqlite3_column_int64(stmt, i))); break;
        case SQLITE_FLOAT: row.emplace_back(sqlite3_column_double(stmt, i)); break;
        default: {
            const auto* text = reinterpret_cast<const char*>(sqlite3_column_text(stmt, i));
            row.emplace_back(text ? std::string(text, size_t(sqlite3_column_bytes(stmt, i))) : std::string());
        }
        }
    }
    return row;
}

SqliteConnection::SqliteConnection(const std::string& path) : path_(path) {
    if (sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_FULLMUTEX,
                        nullptr) != SQLITE_OK) {
        const std::string why = db_ ? sqlite3_errmsg(db_) : "out of memory";
        sqlite3_close(db_);
        throw std::runtime_error("cannot open job store " + path + ": " + why);
    }
    // SQLite opens a file it cannot open for writing (an I/O error, a full
    // disk) read-only instead, without an error: a store that then refuses
    // every write. Starting on it would answer every upload and job 503.
    if (sqlite3_db_readonly(db_, "main") == 1) {
        sqlite3_close(db_);
        throw std::runtime_error("cannot open job store " + path +
                                 " for writing (SQLite opened it read-only: a full disk, an I/O error, or its mode)");
    }
    try {
        configure();
        migrate();
    } catch (...) {
        sqlite3_close(db_);  // the destructor does not run for a constructor that throws
        throw;
    }
    // Readable by lightfarmd's user only (-wal and -shm take the same mode).
    struct stat st {};
    if (::stat(path.c_str(), &st) == 0 && S_ISREG(st.st_mode) && (st.st_mode & 0077)) ::chmod(path.c_str(), 0600);
}

void SqliteConnection::configure() {
    sqlite3_busy_timeout(db_, 5000);
    if (sqlite3_create_function(db_, "lightfarm_now", 0, SQLITE_UTF8, nullptr, sqlite_now, nullptr, nullptr) !=
        SQLITE_OK)
        throw StoreError("job store " + path_ + ": cannot define lightfarm_now(): " + sqlite3_errmsg(db_));
    // WAL + FULL: every commit syncs the WAL before it returns, so a 201 is
    // on the disk when it is answered, through a power loss too. (NORMAL
    // synced only at checkpoints: a killed lightfarmd lost nothing, but a
    // power loss could lose the last jobs answered 201. PostgreSQL's default,
    // synchronous_commit=on, is the same promise.)
    exec("PRAGMA journal_mode=WAL");
    exec("PRAGMA synchronous=FULL");
}

// The tables as they are now, then the columns a store created by an older
// lightfarmd lacks.
void SqliteConnection::migrate() {
    exec(kSchema);
    // A store created before jobs had `latest` (the newest file per output).
    if (!has_column("jobs", "latest")) exec("ALTER TABLE jobs ADD COLUMN latest TEXT NOT NULL DEFAULT '{}'");
    // A store created before leases (scale-out): its running jobs are taken
    // over at start like any other (take_over_abandoned).
    if (!has_column("jobs", "node")) {
        exec("ALTER TABLE jobs ADD COLUMN node TEXT NOT NULL DEFAULT ''");
        exec("ALTER TABLE jobs ADD COLUMN lease_expires REAL NOT NULL DEFAULT 0");
    }
    // A store created before each owner had its own name for a scene: every
    // owner keeps the name the scene was stored under (its first upload's).
    if (!has_column("scene_owners", "name"))
        exec(
            "BEGIN IMMEDIATE; ALTER TABLE scene_owners ADD COLUMN name TEXT NOT NULL DEFAULT ''; "
            "UPDATE scene_owners SET name = COALESCE((SELECT main_file FROM scenes WHERE scenes.id = "
            "scene_owners.scene), ''); COMMIT");
    // A store created before progress events were coalesced: its progress
    // rows are kept (permanent) until compact_events() reaches their jobs.
    if (!has_column("events", "coalesce_key")) {
        exec("ALTER TABLE events ADD COLUMN coalesce_key TEXT");
        exec("ALTER TABLE events ADD COLUMN permanent INTEGER NOT NULL DEFAULT 1");
        if (sqlite3_exec(db_,
                         "UPDATE events SET coalesce_key = COALESCE(json_extract(data, '$.output'), '') "
                         "WHERE type = 'progress'",
                         nullptr, nullptr, nullptr) != SQLITE_OK)
            exec("UPDATE events SET coalesce_key = '' WHERE type = 'progress'");
    }
}

bool SqliteConnection::has_column(const char* table, const std::string& column) {
    const SqlResult columns = run("cannot read the schema", std::string("PRAGMA table_info(") + table + ")", {});
    for (size_t i = 0; i < columns.rows.size(); ++i)
        if (columns.text(i, 1) == column) return true;
    return false;
}

void SqliteConnection::exec(const char* sql) {
    char* message = nullptr;
    if (sqlite3_exec(db_, sql, nullptr, nullptr, &message) != SQLITE_OK) {
        const std::string why = message ? message : "unknown error";
        sqlite3_free(message);
        throw StoreError("job store " + path_ + ": " + why, sqlite_store_cause(sqlite3_errcode(db_)));
    }
}

SqlResult SqliteConnection::run(const char* what, const std::string& sql, const std::vector<SqlValue>& params) {
    sqlite3_stmt* prepared = nullptr;
    if (sqlite3_prepare_v2(db_, sql.c_str(), int(sql.size()), &prepared, nullptr) != SQLITE_OK) store_failed(db_, what);
    const std::unique_ptr<sqlite3_stmt, int (*)(sqlite3_stmt*)> stmt(prepared, sqlite3_finalize);
    for (size_t i = 0; i < params.size(); ++i) bind(stmt.get(), int(i + 1), params[i]);
    SqlResult result;
    // Every row, then SQLITE_DONE: in autocommit mode a write's commit is
    // part of its last step, and its failure lands here.
    for (int rc = sqlite3_step(stmt.get()); rc != SQLITE_DONE; rc = sqlite3_step(stmt.get())) {
        if (rc != SQLITE_ROW) store_failed(db_, what);
        result.rows.push_back(row_of(stmt.get()));
    }
    result.changed = sqlite3_stmt_readonly(stmt.get()) ? 0 : sqlite3_changes(db_);
    return result;
}

void SqliteConnection::begin() {
    // IMMEDIATE: the write lock now, so that no other connection's write can
    // slip in between this transaction's reads and writes.
    if (sqlite3_exec(db_, "BEGIN IMMEDIATE", nullptr, nullptr, nullptr) != SQLITE_OK)
        store_failed(db_, "cannot begin a transaction");
}

void SqliteConnection::commit() {
    if (sqlite3_exec(db_, "COMMIT", nullptr, nullptr, nullptr) != SQLITE_OK) {
        const std::string why = sqlite3_errmsg(db_);
        // A failed COMMIT may leave the transaction open: end it, so the next
        // call starts clean, and say what failed.
        if (sqlite3_get_autocommit(db_) == 0) rollback();
        throw StoreError("job store: commit failed: " + why, sqlite_store_cause(sqlite3_errcode(db_)));
    }
}

}  // namespace

void SqliteJobStore::simulate_full_disk_for_tests(bool fail) {
    static std::once_flag installed;
    std::call_once(installed, install_fault_vfs);
    g_full_disk = fail;
}

SqliteJobStore::SqliteJobStore(const std::string& path, NodeIdentity node)
    : SqlJobStore(std::make_unique<SqliteConnection>(path), std::move(node)) {}

}  // namespace lf::server
