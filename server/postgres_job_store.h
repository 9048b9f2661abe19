// JobStore in a PostgreSQL database that many lightfarmd nodes share
// (`lightfarmd --store postgresql://USER@HOST:PORT/DB`, docs/scale-out.md):
// SqlJobStore's statements over a libpq connection.
//
// The schema is versioned (table schema_version) and migrated at start; a
// database with a newer schema than this lightfarmd knows is refused.
//
// A lost connection (database restarted, network cut) fails the call in
// progress with a StoreError, and the next call connects again.
#pragma once

#include "sql_job_store.h"

#include <cstdint>
#include <string>

namespace lf::server {

// What a tenant is told of a failed PostgreSQL statement (StoreError::cause):
// from its SQLSTATE ("" when there is none), or that the connection is lost.
std::string postgres_store_cause(const std::string& sqlstate, bool connection_lost);

class PostgresJobStore : public SqlJobStore {
public:
    // The newest schema this lightfarmd knows (its migrations: postgres_job_store.cpp).
    static constexpr int kSchemaVersion = 2;

    // Connects to `uri` (a libpq connection URI) and migrates the schema.
    // Throws std::invalid_argument for a URI libpq cannot read, StoreError
    // when the database cannot be reached or migrated, std::runtime_error
    // when its schema is newer than kSchemaVersion.
    PostgresJobStore(const std::string& uri, NodeIdentity node = {});

    // "user@host:port/db": the database as messages name it (never a password).
    const std::string& where() const;

    // Test hook: the number of statements sent so far (docs/BENCHMARKS.md's
    // per-job query counts).
    int64_t statements_sent() const;
};

}  // namespace lf::server
