// An error that becomes an HTTP answer: status + {"error": message, ...}.
// Thrown anywhere below a route; the route wrapper turns it into JSON.
#pragma once

#include <nlohmann/json.hpp>

#include <stdexcept>
#include <string>

namespace lf::server {

class HttpError : public std::runtime_error {
public:
    HttpError(int status, const std::string& message, nlohmann::json extra = nlohmann::json::object())
        : std::runtime_error(message), status_(status), extra_(std::move(extra)) {}
    int status() const { return status_; }
    nlohmann::json body() const {
        nlohmann::json j = extra_;
        j["error"] = what();
        return j;
    }

private:
    int status_;
    nlohmann::json extra_;
};

}  // namespace lf::server
