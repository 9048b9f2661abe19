#include "startup.h"

#include "data_dir.h"
#include "hash.h"
#include "log.h"
#include "service.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <thread>

namespace lf::server {

namespace fs = std::filesystem;

namespace {

// Where the data lives without --data: the user's data directory (XDG), never
// the current directory (a checkout would commit the tokens).
std::string default_data_dir() {
    if (const char* xdg = std::getenv("XDG_DATA_HOME"); xdg && xdg[0] == '/')
        return (fs::path(xdg) / "lightfarm").string();
    if (const char* home = std::getenv("HOME"); home && home[0] == '/')
        return (fs::path(home) / ".local" / "share" / "lightfarm").string();
    throw std::runtime_error("neither XDG_DATA_HOME nor HOME is set: say where the data goes with --data DIR");
}

// One lightfarmd per data directory: an exclusive flock on DATA/lightfarmd.lock,
// held (fd kept open, close-on-exec so no worker inherits it) until the
// process ends, however it ends. The file holds the holder's pid.
void lock_data_dir(const std::string& data_dir) {
    const std::string path = (fs::path(data_dir) / "lightfarmd.lock").string();
    const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0600);
    if (fd < 0) throw std::runtime_error("cannot open " + path + ": " + strerror(errno));
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
        const int e = errno;
        char buf[32] = {};
        const ssize_t n = ::pread(fd, buf, sizeof buf - 1, 0);
        ::close(fd);
        std::string holder = n > 0 ? std::string(buf, size_t(n)) : "";
        while (!holder.empty() && (holder.back() == '\n' || holder.back() == ' ')) holder.pop_back();
        if (e == EWOULDBLOCK)
            throw std::runtime_error("another lightfarmd" + (holder.empty() ? "" : " (pid " + holder + ")") +
                                     " is using the data directory " + data_dir +
                                     "; stop it first, or give this one its own --data DIR");
        throw std::runtime_error("cannot lock " + path + ": " + strerror(e));
    }
    const std::string pid = std::to_string(getpid()) + "\n";
    if (::ftruncate(fd, 0) != 0 || ::pwrite(fd, pid.data(), pid.size(), 0) != ssize_t(pid.size()))
        log_line("cannot write the pid into " + path + " (the lock holds regardless)");
    // fd stays open for the life of the process: that is the lock.
}

// Directories under DATA/jobs and DATA/scenes (the stored jobs' and scenes').
std::vector<fs::path> record_dirs(const std::string& data_dir) {
    std::vector<fs::path> dirs;
    const DataDir data(data_dir);
    for (const fs::path& kind : {data.jobs(), data.scenes()}) {
        std::error_code ec;
        for (fs::directory_iterator it(kind, ec), end; !ec && it != end; it.increment(ec))
            if (it->is_directory(ec)) dirs.push_back(it->path());
    }
    return dirs;
}

// Two live nodes of one name on a shared store would renew, and take over,
// each other's leases: a node refuses a name whose heartbeat still
// advances. A recent heartbeat alone may be this node's own from before a
// crash, so it is watched for one renewal period (a third of that node's
// lease) before the name is taken; a node that stopped cleanly signed off,
// and its name is free at once.
void check_node_name_is_free(const ServerConfig& config) {
    const std::unique_ptr<JobStore> store = open_job_store(config);
    const std::string& name = store->node().name;
    const auto record = [&]() -> std::optional<NodeRecord> {
        for (const NodeRecord& n : store->nodes())
            if (n.name == name) return n;
        return std::nullopt;
    };
    const std::optional<NodeRecord> before = record();
    if (!before || !before->alive()) return;  // signed off, or stopped renewing: the name is free
    const double lease = before->lease_seconds();
    log_line("a node named " + name + " renewed its heartbeat " + std::to_string(int(before->heartbeat_age)) +
             " s ago: watching it for " + std::to_string(int(lease / 3 + 1)) +
             " s (alive, or this node before a restart?)");
    std::this_thread::sleep_for(std::chrono::duration<double>(lease / 3 + 1.0));
    const std::optional<NodeRecord> after = record();
    if (after && after->heartbeat_at > before->heartbeat_at)
        throw std::runtime_error("--node-name " + name +
                                 " is taken: another lightfarmd of that name is alive on this store (its heartbeat "
                                 "advanced while this one watched it); give every node its own --node-name");
}

// A store that lost its records (kill -9 and a lost jobs.sqlite-wal, a
// deleted jobs.sqlite) must not start silently empty beside the jobs it lost:
// refuse, unless --accept-empty-store, which moves the orphaned directories to
// DATA/orphaned-<time>/ (kept for the operator, invisible to the service).
// With a store that holds records, job directories it does not know are
// logged (a partial loss), not refused.
void check_store_against_data_dir(const ServerConfig& config) {
    const fs::path data = config.data_dir;
    const std::unique_ptr<JobStore> opened = open_job_store(config);
    JobStore& store = *opened;
    const std::vector<fs::path> dirs = record_dirs(config.data_dir);
    if (store.empty()) {
        if (dirs.empty()) return;
        const std::string which = config.store.empty() ? (data / "jobs.sqlite").string() : "given by --store";
        const std::string lost =
            config.store.empty() ? "was jobs.sqlite or jobs.sqlite-wal lost?" : "a new or different database?";
        const std::string restore = config.store.empty() ? "Restore jobs.sqlite with its -wal file from a backup"
                                                         : "Give the database these directories belong to";
        if (!config.accept_empty_store)
            throw std::runtime_error(
                "the job store " + which + " is empty, but " + std::to_string(dirs.size()) +
                " job and scene directories are in " + data.string() + " (" + lost + "). " + restore +
                ", or start with --accept-empty-store to begin with an empty store (the directories are moved to " +
                (data / "orphaned-TIME").string() + ", not deleted)");
        char stamp[32];
        const std::time_t t = std::time(nullptr);
        std::tm tm{};
        gmtime_r(&t, &tm);
        std::strftime(stamp, sizeof stamp, "%Y%m%dT%H%M%SZ", &tm);
        const fs::path aside = data / (std::string("orphaned-") + stamp);
        for (const fs::path& dir : dirs) {
            const fs::path to = aside / dir.parent_path().filename() / dir.filename();
            fs::create_directories(to.parent_path());
            fs::rename(dir, to);
        }
        log_line("--accept-empty-store: starting with an empty store; moved " + std::to_string(dirs.size()) +
                 " orphaned job and scene directories to " + aside.string());
        return;
    }
    const std::vector<std::string> unknown = jobs_without_records(config.data_dir, store);
    if (!unknown.empty())
        log_line("warning: " + std::to_string(unknown.size()) + " job directories in " + DataDir(data).jobs().string() +
                 " are not in the job store (lost records?), e.g. " + unknown.front() +
                 "; they are left alone, GET of their jobs answers 410 and /healthz counts them");
}

// Serves until a stop signal, which one thread waits for and answers by
// stopping the service; every other thread (httplib's, the workers')
// inherited the blocked mask.
void serve_until_signalled(Service& service, const sigset_t& stop_signals) {
    std::atomic<bool> ran{false};
    std::thread signal_thread([&service, &ran, stop_signals] {
        int sig = 0;
        sigwait(&stop_signals, &sig);
        if (ran) return;
        log_line(std::string("stopping (") + strsignal(sig) + ")");
        // Until run() has returned: a signal that came while run() was
        // still starting (before it listened) must not be lost.
        while (!ran) {
            service.stop();
            std::this_thread::sleep_for(std::chrono::milliseconds(50));
        }
    });
    service.run();
    ran = true;
    // run() also returns when the listener fails; wake the signal thread
    // (the signal stays pending if it already got one) so it can be joined
    // before `service` goes away.
    kill(getpid(), SIGTERM);
    signal_thread.join();
}

}  // namespace

// The data directory: made (0700) and resolved, and claimed: locked for
// this lightfarmd with the embedded store; with a shared store (--store)
// every node may use the same one (the store arbitrates, and files are
// written under unique names and renamed), under a node name of its own.
void open_data_dir(ServerConfig& config) {
    if (config.data_dir.empty()) config.data_dir = default_data_dir();
    fs::create_directories(config.data_dir);
    config.data_dir = fs::canonical(config.data_dir).string();
    // The data directory itself too, when it existed with a wider mode.
    if (struct stat st{};
        ::stat(config.data_dir.c_str(), &st) == 0 && (st.st_mode & 0077) && ::chmod(config.data_dir.c_str(), 0700) == 0)
        log_line("made " + config.data_dir + " readable by its owner only (0700)");
    if (config.store.empty()) lock_data_dir(config.data_dir);
    else check_node_name_is_free(config);
    check_store_against_data_dir(config);
}

// The tokens to accept: --tokens FILE, else DATA/tokens, created with one new
// random token (readable by this user only) when it does not exist.
std::vector<std::string> load_tokens(ServerConfig& config, bool& created) {
    created = false;
    if (config.tokens_file.empty()) {
        config.tokens_file = (fs::path(config.data_dir) / "tokens").string();
        if (!fs::exists(config.tokens_file)) {
            // A name of its own, then link(), which never replaces: of nodes
            // starting together on a shared data directory, the first one's
            // file stays and every node reads it.
            const std::string tmp = config.tokens_file + "." + random_hex(8) + ".tmp";
            {
                std::ofstream out(tmp);
                out << "# lightfarmd bearer tokens, one per line (created by lightfarmd)\n" << random_hex(24) << "\n";
                if (!out) throw std::runtime_error("cannot write " + tmp);
            }
            chmod(tmp.c_str(), 0600);
            created = ::link(tmp.c_str(), config.tokens_file.c_str()) == 0;
            const int link_error = errno;
            fs::remove(tmp);
            if (!created && link_error != EEXIST)
                throw std::runtime_error("cannot create " + config.tokens_file + ": " + strerror(link_error));
        }
    }
    std::vector<std::string> tokens = read_tokens(config.tokens_file);
    if (tokens.empty())
        throw std::runtime_error("no token in " + config.tokens_file + ": nobody could use the service");
    return tokens;
}

// Writes DATA/lightfarmd.url (atomically) so that scripts and tests started
// with --listen HOST:0 find the port.
void write_url_file(const ServerConfig& config, const std::string& url) {
    const fs::path path = fs::path(config.data_dir) / "lightfarmd.url";
    const fs::path tmp = path.string() + "." + random_hex(8) + ".tmp";
    std::ofstream out(tmp);
    out << url << "\n";
    out.close();
    // An empty URL file would leave whoever waits for it waiting: no start.
    if (!out) {
        const std::string why = std::strerror(errno);
        fs::remove(tmp);
        throw std::runtime_error("cannot write " + path.string() + " (" + why + ")");
    }
    chmod(tmp.c_str(), 0600);
    fs::rename(tmp, path);
}

// A first start's token, and how to use it: commands that run as printed,
// from any directory (the CLI by the path it was found at: nothing puts a
// source build's binaries on PATH).
void print_new_token(const ServerConfig& config, const std::string& token, const std::string& url) {
    log_line("no --tokens file given: created " + config.tokens_file + " with a new token");
    std::string cli = find_engine(config.engine);
    if (cli.find_first_of(" '\"\\$`") != std::string::npos) cli = "'" + cli + "'";
    std::cout << "lightfarmd: token: " << token << "\n"
              << "  submit a bake:  LIGHTFARM_TOKEN=" << token << " " << cli << " submit scene.glb --server " << url
              << " --wait\n"
              << "  with curl:      curl -H 'Authorization: Bearer " << token
              << "' -H 'Content-Type: model/gltf-binary' --data-binary @scene.glb " << url << "/v1/scenes\n"
              << "  status page:    " << url << "/?token=" << token << "\n"
              << std::flush;
}

void run_service(ServerConfig config, const sigset_t& stop_signals) {
    open_data_dir(config);
    bool created = false;
    const std::vector<std::string> tokens = load_tokens(config, created);
    Service service(config, tokens);
    const int port = service.bind();
    const std::string url = "http://" + config.host + ":" + std::to_string(port);
    write_url_file(config, url);

    log_line("listening on " + url + ", data in " + config.data_dir);
    if (created) print_new_token(config, tokens.front(), url);
    else log_line("tokens from " + config.tokens_file + " (" + std::to_string(tokens.size()) + ")");

    serve_until_signalled(service, stop_signals);
    log_line("stopped");
}

}  // namespace lf::server
