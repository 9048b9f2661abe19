// lightfarmd's start and stop, between parsing its command line and serving:
// the data directory claimed, the tokens loaded (or a first one created), the
// port found, the URL file written, and the service run until a stop signal.
// server/main.cpp parses the arguments and blocks the signals; the rest is
// here, where a test can call it.
#pragma once

#include "config.h"

#include <signal.h>

#include <string>
#include <vector>

namespace lf::server {

// The data directory: made (0700) and resolved (config.data_dir becomes its
// canonical path; without --data, the user's XDG data directory), and
// claimed: locked for this lightfarmd with the embedded store; with a shared
// store (--store) every node may use the same one (the store arbitrates, and
// files are written under unique names and renamed), under a node name of its
// own. Throws when another lightfarmd holds it, when the node name is taken,
// or when the store lost the records of the directories there.
void open_data_dir(ServerConfig& config);

// The tokens to accept: --tokens FILE, else DATA/tokens (config.tokens_file
// is set to it), created with one new random token (readable by this user
// only) when it does not exist; `created` says whether this call made it.
// Throws when the file holds no token.
std::vector<std::string> load_tokens(ServerConfig& config, bool& created);

// Writes DATA/lightfarmd.url (atomically) so that scripts and tests started
// with --listen HOST:0 find the port.
void write_url_file(const ServerConfig& config, const std::string& url);

// A first start's token on stdout, and commands that use it, runnable as
// printed from any directory.
void print_new_token(const ServerConfig& config, const std::string& token, const std::string& url);

// Everything above, then serves until one of `stop_signals` arrives (the
// caller blocks them in every thread first: they are taken by sigwait) or
// the listener fails. Throws what a start-up step throws.
void run_service(ServerConfig config, const sigset_t& stop_signals);

}  // namespace lf::server
