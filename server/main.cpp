// lightfarmd: the bake service. With no arguments it serves on
// 127.0.0.1:8750 with its data in ./lightfarm-data and a token it creates
// there, so `scripts/run` gives a working local service.
#include "config.h"
#include "hash.h"
#include "log.h"
#include "service.h"

#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iostream>
#include <thread>

namespace fs = std::filesystem;
using namespace lf::server;

namespace {

// The tokens to accept: --tokens FILE, else DATA/tokens, created with one new
// random token (readable by this user only) when it does not exist.
std::vector<std::string> load_tokens(ServerConfig& config, bool& created) {
    created = false;
    if (config.tokens_file.empty()) {
        config.tokens_file = (fs::path(config.data_dir) / "tokens").string();
        if (!fs::exists(config.tokens_file)) {
            const std::string tmp = config.tokens_file + ".tmp";
            {
                std::ofstream out(tmp);
                out << "# lightfarmd bearer tokens, one per line (created by lightfarmd)\n" << random_hex(24) << "\n";
                if (!out) throw std::runtime_error("cannot write " + tmp);
            }
            chmod(tmp.c_str(), 0600);
            fs::rename(tmp, config.tokens_file);
            created = true;
        }
    }
    std::vector<std::string> tokens = read_tokens(config.tokens_file);
    if (tokens.empty()) throw std::runtime_error("no token in " + config.tokens_file + ": nobody could use the service");
    return tokens;
}

// Writes DATA/lightfarmd.url (atomically) so that scripts and tests started
// with --listen HOST:0 find the port.
void write_url_file(const ServerConfig& config, const std::string& url) {
    const fs::path path = fs::path(config.data_dir) / "lightfarmd.url";
    const fs::path tmp = path.string() + ".tmp";
    std::ofstream(tmp) << url << "\n";
    fs::rename(tmp, path);
}

}  // namespace

int main(int argc, char** argv) {
    ServerConfig config;
    try {
        bool help = false;
        config = parse_server_args(std::vector<std::string>(argv + 1, argv + argc), help);
        if (help) {
            std::cout << kServerUsage;
            return 0;
        }
    } catch (const std::exception& e) {
        std::cerr << "lightfarmd: " << e.what() << "\n" << kServerUsage;
        return 2;
    }

    // Signals go to one thread that stops the service cleanly; every other
    // thread (httplib's, the workers') inherits the blocked mask. SIGPIPE is
    // ignored: a client that hangs up must not end the server.
    signal(SIGPIPE, SIG_IGN);
    sigset_t stop_signals;
    sigemptyset(&stop_signals);
    sigaddset(&stop_signals, SIGINT);
    sigaddset(&stop_signals, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);

    try {
        fs::create_directories(config.data_dir);
        config.data_dir = fs::canonical(config.data_dir).string();
        bool created = false;
        const std::vector<std::string> tokens = load_tokens(config, created);
        Service service(config, tokens);
        const int port = service.bind();
        const std::string url = "http://" + config.host + ":" + std::to_string(port);
        write_url_file(config, url);

        log_line("listening on " + url + ", data in " + config.data_dir);
        if (created) {
            log_line("no --tokens file given: created " + config.tokens_file + " with a new token");
            std::cout << "lightfarmd: token: " << tokens.front() << "\n"
                      << "  submit a bake:  LIGHTFARM_TOKEN=" << tokens.front() << " lightfarm submit scene.glb --server " << url << " --wait\n"
                      << "  with curl:      curl -H 'Authorization: Bearer " << tokens.front() << "' -H 'Content-Type: model/gltf-binary' --data-binary @scene.glb " << url << "/v1/scenes\n"
                      << "  status page:    " << url << "/?token=" << tokens.front() << "\n"
                      << std::flush;
        } else {
            log_line("tokens from " + config.tokens_file + " (" + std::to_string(tokens.size()) + ")");
        }

        std::thread signal_thread([&service, stop_signals] {
            int sig = 0;
            sigwait(&stop_signals, &sig);
            log_line(std::string("stopping (") + strsignal(sig) + ")");
            service.stop();
        });
        service.run();
        // run() also returns when the listener fails; wake the signal thread
        // (the signal stays pending if it already got one) so it can be joined
        // before `service` goes away.
        kill(getpid(), SIGTERM);
        signal_thread.join();
        log_line("stopped");
        return 0;
    } catch (const std::exception& e) {
        log_line(std::string("error: ") + e.what());
        return 1;
    }
}
