// SHA-256 (OpenSSL's libcrypto, already a dependency of Debian's cpp-httplib)
// and random ids. Scene ids and bake cache keys are content hashes.
#pragma once

#include <memory>
#include <string>
#include <string_view>

namespace lf::server {

// Incremental SHA-256: update() any number of times, then hex() once.
class Sha256 {
public:
    Sha256();
    ~Sha256();
    Sha256(const Sha256&) = delete;
    Sha256& operator=(const Sha256&) = delete;
    void update(std::string_view bytes);
    std::string hex();  // 64 lowercase hex digits

private:
    struct State;
    std::unique_ptr<State> state_;
};

std::string sha256_hex(std::string_view bytes);
// The digest in base64 (RFC 4648), as a Content-Security-Policy hash source takes it.
std::string sha256_base64(std::string_view bytes);

// `bytes` random bytes from the OS, as 2*bytes hex digits (ids, tokens).
std::string random_hex(size_t bytes);

}  // namespace lf::server
