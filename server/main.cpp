// lightfarmd: the bake service. With no arguments it serves on
// 127.0.0.1:8750 with its data in $XDG_DATA_HOME/lightfarm (else
// ~/.local/share/lightfarm) and a token it creates there, so `scripts/run`
// gives a working local service.
//
// main() reads the command line and readies the process (signals, umask);
// the start-up and the serving are lf::server::run_service (startup.h).
#include "config.h"
#include "log.h"
#include "startup.h"

#include <signal.h>
#include <sys/stat.h>

#include <iostream>
#include <string>
#include <vector>

using namespace lf::server;

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

    // Everything lightfarmd and its workers create is this user's only:
    // files 0600, directories 0700.
    umask(077);

    try {
        run_service(config, stop_signals);
        return 0;
    } catch (const std::exception& e) {
        log_line(std::string("error: ") + e.what());
        return 1;
    }
}
