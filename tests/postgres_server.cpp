#include "postgres_server.h"

#include "subprocess.h"

#include <netinet/in.h>
#include <pwd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <fstream>
#include <iterator>
#include <random>
#include <stdexcept>
#include <thread>

namespace lf::test {

namespace fs = std::filesystem;

namespace {

// Debian puts the server's programs in /usr/lib/postgresql/VERSION/bin: the newest.
std::string find_postgres_bin() {
    std::vector<fs::path> found;
    std::error_code ec;
    for (fs::directory_iterator it("/usr/lib/postgresql", ec), end; !ec && it != end; it.increment(ec))
        if (fs::exists(it->path() / "bin" / "initdb")) found.push_back(it->path() / "bin");
    if (found.empty())
        throw std::runtime_error(
            "PostgreSQL's server is not installed (no /usr/lib/postgresql/*/bin/initdb): the PostgreSQL store's tests "
            "need it. Install it with `apt-get install postgresql libpq-dev` (scripts/test does)");
    std::sort(found.begin(), found.end(), [](const fs::path& a, const fs::path& b) {
        return std::stoi(a.parent_path().filename().string()) < std::stoi(b.parent_path().filename().string());
    });
    return found.back().string();
}

}  // namespace

int free_loopback_port() {
    const int s = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t n = sizeof a;
    if (s < 0 || ::bind(s, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
        ::getsockname(s, reinterpret_cast<sockaddr*>(&a), &n) != 0)
        throw std::runtime_error("no free loopback port for PostgreSQL");
    ::close(s);
    return ntohs(a.sin_port);
}

PostgresServer::PostgresServer(bool durable)
    : bin_(find_postgres_bin()), as_postgres_(::geteuid() == 0), durable_(durable) {
    std::random_device rd;
    dir_ = fs::temp_directory_path() / ("lightfarm-pg-" + std::to_string(::getpid()) + "-" + std::to_string(rd()));
    fs::create_directories(dir_);
    if (as_postgres_) {
        const passwd* pg = ::getpwnam("postgres");
        if (!pg)
            throw std::runtime_error(
                "running as root, but there is no user postgres to run PostgreSQL as "
                "(`apt-get install postgresql` creates it)");
        if (::chown(dir_.c_str(), pg->pw_uid, pg->pw_gid) != 0)
            throw std::runtime_error("cannot give " + dir_.string() + " to user postgres");
    }
    port_ = free_loopback_port();
    run({bin_ + "/initdb", "--pgdata", (dir_ / "data").string(), "--username", "postgres", "--auth", "trust",
         "--no-sync", "--encoding", "UTF8"});
    start();
}

PostgresServer::~PostgresServer() {
    try {
        if (running_) run({bin_ + "/pg_ctl", "--pgdata", (dir_ / "data").string(), "--mode", "immediate", "stop"});
    } catch (const std::exception&) {
        // best effort: the directory goes regardless
    }
    std::error_code ec;
    fs::remove_all(dir_, ec);
}

std::string PostgresServer::run(const std::vector<std::string>& argv) const {
    std::vector<std::string> full = argv;
    if (as_postgres_) full.insert(full.begin(), {"/usr/sbin/runuser", "-u", "postgres", "--"});
    // `--` keeps runuser's own options apart; stderr joins stdout for the message.
    const server::RunResult r = server::run_command(full, std::chrono::seconds(60));
    if (!r.status.success() || r.timed_out)
        throw std::runtime_error(argv.front() + " failed (" + (r.timed_out ? "timed out" : r.status.describe()) +
                                 "): " + r.out + r.err_last_line);
    return r.out;
}

void PostgresServer::start(const std::vector<std::string>& environment) {
    // A socket directory of its own, loopback only; fast and throwaway
    // (no fsync) unless durable.
    std::string options = "-p " + std::to_string(port_) + " -k " + dir_.string() +
                          " -c listen_addresses=127.0.0.1 -c max_connections=200";
    if (!durable_) options += " -c fsync=off -c synchronous_commit=off -c full_page_writes=off";
    // env(1) rather than this process's environment: runuser may not pass it on.
    std::vector<std::string> argv = {"/usr/bin/env"};
    argv.insert(argv.end(), environment.begin(), environment.end());
    argv.insert(argv.end(), {bin_ + "/pg_ctl", "--pgdata", (dir_ / "data").string(), "--log",
                             (dir_ / "server.log").string(), "--wait", "--options", options, "start"});
    run(argv);
    running_ = true;
}

void PostgresServer::wait_until_ready(std::chrono::seconds timeout) const {
    const auto until = std::chrono::steady_clock::now() + timeout;
    for (;;) {
        const server::RunResult r = server::run_command(
            {bin_ + "/pg_isready", "--host", "127.0.0.1", "--port", std::to_string(port_), "--timeout", "1"},
            std::chrono::seconds(5));
        if (r.status.success()) return;
        if (std::chrono::steady_clock::now() > until) {
            std::ifstream log(dir_ / "server.log");
            const std::string text((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
            throw std::runtime_error("PostgreSQL did not accept connections again; its log ends:\n" +
                                     text.substr(text.size() > 2000 ? text.size() - 2000 : 0));
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
}

void PostgresServer::stop() {
    run({bin_ + "/pg_ctl", "--pgdata", (dir_ / "data").string(), "--mode", "fast", "--wait", "stop"});
    running_ = false;
}

std::string PostgresServer::create_database() {
    const std::string name = "lightfarm_" + std::to_string(++databases_);
    run({bin_ + "/createdb", "--host", "127.0.0.1", "--port", std::to_string(port_), "--username", "postgres", name});
    return "postgresql://postgres@127.0.0.1:" + std::to_string(port_) + "/" + name;
}

void PostgresServer::sql(const std::string& uri, const std::string& command) const {
    run({bin_ + "/psql", "--no-psqlrc", "--quiet", "--set", "ON_ERROR_STOP=1", "--dbname", uri, "--command", command});
}

}  // namespace lf::test
