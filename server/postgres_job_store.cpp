#include "postgres_job_store.h"

#include <libpq-fe.h>

#include <atomic>
#include <memory>
#include <stdexcept>

namespace lf::server {

// SQLSTATE classes (PostgreSQL's appendix A): 53 insufficient resources
// (53100 disk full), 08 connection exceptions, 25006 a read-only
// transaction, 57P0x the server shutting down, 55P03 / 57014 a lock or
// statement timeout.
std::string postgres_store_cause(const std::string& sqlstate, bool connection_lost) {
    if (connection_lost || sqlstate.rfind("08", 0) == 0 || sqlstate.rfind("57P0", 0) == 0)
        return "it cannot be reached";
    if (sqlstate == "53100") return "its disk is full";
    if (sqlstate.rfind("53", 0) == 0) return "it is out of resources";
    if (sqlstate == "25006") return "it is read-only";
    if (sqlstate == "55P03" || sqlstate == "57014" || sqlstate == "40001" || sqlstate == "40P01") return "it is busy";
    if (sqlstate.rfind("58", 0) == 0) return "its disk answered with an I/O error";
    return StoreError::kFailed;
}

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
    // Each owner its own name for a scene (tenants uploading the same bytes
    // see each their own); the owners so far keep the name it was stored under.
    {2, R"sql(
ALTER TABLE scene_owners ADD COLUMN name TEXT NOT NULL DEFAULT '';
UPDATE scene_owners SET name = scenes.main_file FROM scenes WHERE scenes.id = scene_owners.scene;
)sql"},
};
static_assert(std::size(kMigrations) == PostgresJobStore::kSchemaVersion, "one migration per schema version");

constexpr SqlDialect kPostgresDialect = {
    // Leases and heartbeats are timed by the database's clock: the nodes'
    // clocks may disagree, the database's is one.
    .now = "extract(epoch from clock_timestamp())",
    .for_update = " FOR UPDATE",
    .for_update_skip_locked = " FOR UPDATE SKIP LOCKED",
    // JSON is stored as text (the schema's, as SQLite's); JSONB merges a key in.
    .latest_with_key = "CAST(CAST(latest AS JSONB) || jsonb_build_object(CAST(? AS TEXT), CAST(? AS JSONB)) AS TEXT)",
    .writable_ctes = true,
    .shared = true,
};

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

std::string describe_database(PGconn* conn) {
    const char* user = PQuser(conn);
    const char* host = PQhost(conn);
    const char* port = PQport(conn);
    const char* db = PQdb(conn);
    return std::string(user ? user : "?") + "@" + (host ? host : "?") + ":" + (port ? port : "?") + "/" +
           (db ? db : "?");
}

constexpr const char* kUnreachable = "it cannot be reached";

std::string first_line(const char* message) {
    std::string m = message ? message : "";
    while (!m.empty() && (m.back() == '\n' || m.back() == ' ')) m.pop_back();
    return m;
}

// One statement's result, freed with it.
struct ResultDeleter {
    void operator()(PGresult* r) const { PQclear(r); }
};
using PgResult = std::unique_ptr<PGresult, ResultDeleter>;

// The rows of a statement that succeeded, as text (NULL as SQL NULL).
SqlResult result_of(PGresult* r) {
    SqlResult result;
    for (int row = 0; row < PQntuples(r); ++row) {
        std::vector<SqlValue>& values = result.rows.emplace_back();
        for (int column = 0; column < PQnfields(r); ++column) {
            if (PQgetisnull(r, row, column)) values.emplace_back(nullptr);
            else values.emplace_back(std::string(PQgetvalue(r, row, column), size_t(PQgetlength(r, row, column))));
        }
    }
    const char* changed = PQcmdTuples(r);
    result.changed = changed && changed[0] ? std::stoll(changed) : 0;
    return result;
}

class PostgresConnection : public SqlConnection {
public:
    // Connects and migrates the schema (PostgresJobStore's constructor says what it throws).
    explicit PostgresConnection(const std::string& uri);
    ~PostgresConnection() override { PQfinish(conn_); }
    PostgresConnection(const PostgresConnection&) = delete;
    PostgresConnection& operator=(const PostgresConnection&) = delete;

    const SqlDialect& dialect() const override { return kPostgresDialect; }
    SqlResult run(const char* what, const std::string& sql, const std::vector<SqlValue>& params) override;
    void begin() override { run("cannot begin a transaction", "BEGIN", {}); }
    void commit() override { run("commit failed", "COMMIT", {}); }
    // Best effort, and not counted: a lost connection rolled back already.
    void rollback() noexcept override { PQclear(PQexec(conn_, "ROLLBACK")); }

    const std::string& where() const { return where_; }
    int64_t statements_sent() const { return statements_; }

private:
    // Reconnects when the connection was lost; throws StoreError when it cannot.
    void connect_if_lost();
    void migrate();

    pg_conn* conn_ = nullptr;
    std::string uri_;
    std::string where_;
    std::atomic<int64_t> statements_{0};
};

PostgresConnection::PostgresConnection(const std::string& uri) : uri_(uri) {
    char* error = nullptr;
    PQconninfoOption* options = PQconninfoParse(uri.c_str(), &error);
    if (!options) {
        const std::string why = error ? first_line(error) : "out of memory";
        PQfreemem(error);
        throw std::invalid_argument("--store: '" + uri + "' is not a PostgreSQL connection URI (" + why +
                                    "); write postgresql://USER@HOST:PORT/DB");
    }
    PQconninfoFree(options);
    try {
        connect_if_lost();
        migrate();
    } catch (...) {
        PQfinish(conn_);  // the destructor does not run for a constructor that throws
        throw;
    }
}

void PostgresConnection::connect_if_lost() {
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
        if (!conn_) throw StoreError("job store: cannot connect to PostgreSQL: out of memory", kUnreachable);
        where_ = describe_database(conn_);
        // Notices ("relation already exists, skipping") are not errors: not for the log.
        PQsetNoticeProcessor(
            conn_, [](void*, const char*) {}, nullptr);
    }
    if (PQstatus(conn_) != CONNECTION_OK)
        throw StoreError(
            "job store: cannot connect to PostgreSQL at " + where_ + ": " + first_line(PQerrorMessage(conn_)),
            kUnreachable);
}

SqlResult PostgresConnection::run(const char* what, const std::string& sql, const std::vector<SqlValue>& params) {
    connect_if_lost();
    std::vector<std::string> texts;
    for (const SqlValue& p : params) texts.push_back(sql_text(p));
    std::vector<const char*> values;
    for (size_t i = 0; i < params.size(); ++i)
        values.push_back(std::holds_alternative<std::nullptr_t>(params[i]) ? nullptr : texts[i].c_str());
    ++statements_;
    // Without parameters, the simple protocol: it also takes several commands (a migration).
    const PgResult r(params.empty() ? PQexec(conn_, sql.c_str())
                                    : PQexecParams(conn_, numbered_placeholders(sql).c_str(), int(values.size()),
                                                   nullptr, values.data(), nullptr, nullptr, 0));
    const ExecStatusType status = PQresultStatus(r.get());  // PGRES_FATAL_ERROR for a null result (out of memory)
    if (status != PGRES_COMMAND_OK && status != PGRES_TUPLES_OK) {
        const bool lost = PQstatus(conn_) != CONNECTION_OK;
        const char* sqlstate = PQresultErrorField(r.get(), PG_DIAG_SQLSTATE);
        throw StoreError(std::string("job store: ") + what + ": " +
                             (lost ? "lost the connection to PostgreSQL at " + where_ + ": " : "") +
                             first_line(PQerrorMessage(conn_)),
                         postgres_store_cause(sqlstate ? sqlstate : "", lost));
    }
    return result_of(r.get());
}

void PostgresConnection::migrate() {
    SqlTransaction t(*this);
    run("cannot lock the schema", kMigrationLock, {});
    run("cannot create schema_version", "CREATE TABLE IF NOT EXISTS schema_version(version INTEGER NOT NULL)", {});
    const int current = int(
        run("cannot read schema_version", "SELECT COALESCE(MAX(version), 0) FROM schema_version", {}).integer(0, 0));
    if (current > PostgresJobStore::kSchemaVersion)
        throw std::runtime_error("the job store at " + where_ + " has schema version " + std::to_string(current) +
                                 ", newer than this lightfarmd knows (" +
                                 std::to_string(PostgresJobStore::kSchemaVersion) +
                                 "): a newer lightfarmd migrated it. Run that version here too (every node of a "
                                 "store must be at least as new as its schema)");
    for (const Migration& m : kMigrations) {
        if (m.version <= current) continue;
        const std::string what = "schema migration to version " + std::to_string(m.version) + " failed";
        run(what.c_str(), m.sql, {});
        run(what.c_str(), "INSERT INTO schema_version(version) VALUES(?)", {int64_t(m.version)});
    }
    t.commit();
}

}  // namespace

PostgresJobStore::PostgresJobStore(const std::string& uri, NodeIdentity node)
    : SqlJobStore(std::make_unique<PostgresConnection>(uri), std::move(node)) {}

const std::string& PostgresJobStore::where() const {
    return static_cast<const PostgresConnection&>(connection()).where();
}

int64_t PostgresJobStore::statements_sent() const {
    return static_cast<const PostgresConnection&>(connection()).statements_sent();
}

}  // namespace lf::server
