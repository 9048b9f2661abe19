// A throwaway PostgreSQL server for tests: initdb into a temporary directory,
// started with pg_ctl on a free loopback port (as the postgres user when the
// test runs as root: PostgreSQL refuses root), deleted at the end. No test
// skips when PostgreSQL is missing: the constructor throws, naming what to
// install.
#pragma once

#include <chrono>
#include <filesystem>
#include <string>
#include <vector>

namespace lf::test {

// A loopback TCP port no one listens on now (for a server a test starts); throws if there is none.
int free_loopback_port();

class PostgresServer {
public:
    // initdb + start; throws std::runtime_error saying what failed or is
    // missing. Fast and throwaway by default (no fsync, commits not waited
    // for); `durable`: PostgreSQL's defaults, each commit written and synced
    // to its WAL before it returns (what the fault harness fails).
    explicit PostgresServer(bool durable = false);
    ~PostgresServer();  // stops it (immediately) and deletes its directory

    // A new, empty database; returns its URI (postgresql://postgres@127.0.0.1:PORT/NAME).
    std::string create_database();
    // Runs one SQL command in the database `uri` names (psql); throws on failure.
    void sql(const std::string& uri, const std::string& command) const;

    void stop();  // fast shutdown: clients lose their connections
    // Again, on the same port; `environment` ("NAME=VALUE") is given to the
    // server's processes (the fault harness's shim).
    void start(const std::vector<std::string>& environment = {});
    // Waits until it accepts connections again (after a crash it restarts by
    // itself, recovering from its WAL); throws after `timeout`.
    void wait_until_ready(std::chrono::seconds timeout = std::chrono::seconds(60)) const;
    int port() const { return port_; }
    std::filesystem::path data_dir() const { return dir_ / "data"; }
    // The directory the server's user may write to, for files a test shares with it.
    std::filesystem::path shared_dir() const { return dir_; }

private:
    // Runs a PostgreSQL program as the server's user; throws with its output on failure.
    std::string run(const std::vector<std::string>& argv) const;
    std::filesystem::path dir_;
    std::string bin_;           // the directory of initdb, pg_ctl, createdb, psql
    bool as_postgres_ = false;  // running as root: the programs run as user postgres
    bool durable_ = false;
    int port_ = 0;
    int databases_ = 0;
    bool running_ = false;
};

}  // namespace lf::test
