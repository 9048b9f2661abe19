// JobStore in one SQLite file (DATA/jobs.sqlite): SqlJobStore's statements
// over a SQLite connection. One lightfarmd per file (the data directory's
// lock), so the node's clock is the database's.
#pragma once

#include "sql_job_store.h"

#include <string>

namespace lf::server {

class SqliteJobStore : public SqlJobStore {
public:
    // Creates the schema if needed. `node`: who this lightfarmd is (one per file).
    explicit SqliteJobStore(const std::string& path, NodeIdentity node = {});

    // Test hook: every SQLite database this process opens *after the first
    // call* goes through a VFS that, while `fail` is true, fails each write
    // as a full disk does (SQLITE_FULL); reads still work. lightfarmd never
    // calls it. (As root, chmod cannot make a file unwritable; this can.)
    static void simulate_full_disk_for_tests(bool fail);
};

// What a tenant is told of an SQLite result code (StoreError::cause).
std::string sqlite_store_cause(int code);

}  // namespace lf::server
