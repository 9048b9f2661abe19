// The small layer under SqlJobStore (sql_job_store.h): one connection to a
// database, SQLite or PostgreSQL, that runs a statement or a transaction, and
// the few fragments its dialect writes its own way. Everything else, every
// statement of the store, is written once, in sql_job_store.cpp.
//
// How each database connects, creates and migrates its schema, and fails
// lives with its store: sqlite_job_store.cpp, postgres_job_store.cpp.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <variant>
#include <vector>

namespace lf::server {

// A statement's parameter, or a column's value: NULL, a boolean, an integer,
// a real number or text.
using SqlValue = std::variant<std::nullptr_t, bool, int64_t, double, std::string>;

// A value as SQL text: how PostgreSQL takes its parameters. Reals with every
// digit (%.17g: a time read back is the time written), booleans true/false.
std::string sql_text(const SqlValue& value);

// What a statement returned, all rows read at once (the store's answers are
// small), and how many rows it changed.
struct SqlResult {
    std::vector<std::vector<SqlValue>> rows;
    int64_t changed = 0;  // rows inserted, updated or deleted

    bool empty() const { return rows.empty(); }
    // A column as the store reads it, whatever type the database gave it
    // (PostgreSQL gives text; SQLite its own types). NULL reads as "" or 0.
    std::string text(size_t row, int column) const;
    int64_t integer(size_t row, int column) const;
    double real(size_t row, int column) const;
};

// The fragments that differ between the dialects, spliced into the store's
// statements, and the two ways the databases differ in what they can do.
struct SqlDialect {
    // The clock of leases and heartbeats, in seconds since the epoch: the
    // database's, one clock for every node that shares it.
    const char* now;
    // After a SELECT of rows the transaction goes on to change: the row locks
    // that order other nodes' writes after this one ("" where the whole
    // database is locked for the transaction).
    const char* for_update;
    // After a claim's SELECT: rows another node is claiming right now are
    // skipped, so nodes claiming at once each get a different job.
    const char* for_update_skip_locked;
    // An expression: the JSON object in the text column `latest` with one key
    // (the first parameter, text) set to a JSON value (the second, JSON text).
    const char* latest_with_key;
    // One statement may hold several writes (WITH gone AS (DELETE ...)
    // INSERT ...): one round trip, one snapshot.
    bool writable_ctes;
    // Many lightfarmd nodes share the database; else one has it to itself
    // (SQLite: the data directory's lock allows one lightfarmd per file).
    bool shared;
};

class SqlConnection {
public:
    virtual ~SqlConnection() = default;
    virtual const SqlDialect& dialect() const = 0;

    // Runs one statement: `sql` with a '?' for each of `params`. Throws
    // StoreError "job store: WHAT: why" when it fails. Outside a transaction
    // a write is committed (durably) when run returns.
    virtual SqlResult run(const char* what, const std::string& sql, const std::vector<SqlValue>& params) = 0;

    // A write transaction (SqlTransaction holds one). commit() throws
    // StoreError when the commit fails: then nothing of it was stored.
    virtual void begin() = 0;
    virtual void commit() = 0;
    virtual void rollback() noexcept = 0;
};

// BEGIN ... COMMIT; leaving the scope without commit() rolls back.
class SqlTransaction {
public:
    explicit SqlTransaction(SqlConnection& db) : db_(db) { db_.begin(); }
    ~SqlTransaction() {
        if (!done_) db_.rollback();
    }
    SqlTransaction(const SqlTransaction&) = delete;
    SqlTransaction& operator=(const SqlTransaction&) = delete;
    void commit() {
        done_ = true;  // a failed COMMIT ends the transaction too
        db_.commit();
    }

private:
    SqlConnection& db_;
    bool done_ = false;
};

}  // namespace lf::server
