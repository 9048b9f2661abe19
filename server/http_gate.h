// lightfarmd's connection gate, in front of cpp-httplib (see below). Only
// service.cpp includes it: the routes are the service's, the sockets this.
#pragma once

#include "config.h"
#include "metrics.h"

#include <arpa/inet.h>
#include <httplib.h>
#include <netinet/in.h>
#include <nlohmann/json.hpp>
#include <poll.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <thread>

namespace lf::server {

using json = nlohmann::json;

// ---------------------------------------------------------------------------
// The connection gate.
//
// cpp-httplib 0.11 serves a connection on one pool thread from accept() to
// close: a client that trickles its header lines holds a thread for as long
// as every single read arrives within the read timeout, and 64 of them stop
// the API. Its options (read timeout, keep-alive count and timeout, payload
// length) are per read or per body; none bounds a whole request, none counts
// connections, and the request line is buffered whole before its 414.
//
// So lightfarmd keeps cpp-httplib for parsing, routing and writing answers,
// and takes the sockets before it: Server::process_and_close_socket is
// virtual and Server::process_request (which parses and answers one request
// from any httplib::Stream) is protected. GatedServer's
// process_and_close_socket runs on the listener thread (an inline task
// queue), counts the connection against the caps and hands it to one epoll
// thread that gathers the request line and headers without a request thread,
// bounded in bytes and in time. Only a request whose headers are whole goes
// to a request thread, which reads the body through GateStream under the
// whole request's deadline; a kept-alive connection goes back to the gate
// between requests, so idle connections hold no thread either.
//
// Fair shares (issue #33): an idle connection (nothing sent) is the first
// to be closed when a new one meets a connection cap (make_room_locked), and
// a request with a body takes a request thread only within its token's and
// its address's budgets (start_body_read_locked): one tenant's idle sockets
// or slow bodies cost that tenant, not the others.
// ---------------------------------------------------------------------------

namespace gate {

using Clock = std::chrono::steady_clock;

// What the request being served on this thread learnt below httplib.
struct RequestContext {
    bool close_after = false;  // the body was not read: close once answered
    bool timed_out = false;    // the body did not arrive within request_seconds
    bool over_budget = false;  // the body ran past upload_bytes
};
inline thread_local RequestContext* tl_request = nullptr;

inline constexpr size_t kRequestLineMax = 8192;  // CPPHTTPLIB_REQUEST_URI_MAX_LENGTH
inline constexpr int kMaxRequestsPerConnection = 100;
inline constexpr auto kLinger = std::chrono::seconds(1);
// A client that writes its whole body before it reads (httplib's, Python's
// requests) sees an early answer only if its body was drained, not reset:
// 4 MiB covers a job spec four times over spec_bytes' default (1 MiB covered
// none: a 2 MiB spec's 413 was lost to a reset, and killed its client).
inline constexpr size_t kLingerBytes = 4 << 20;
inline constexpr int kWriteTimeoutMs = 30000;
inline constexpr int kMaxUncountedLingering = 256;

inline std::string canned_response(int status, const char* reason, const json& body, const std::string& headers = "") {
    const std::string text = body.dump(2, ' ', false, json::error_handler_t::replace) + "\n";
    return "HTTP/1.1 " + std::to_string(status) + " " + reason +
           "\r\nContent-Type: application/json\r\nConnection: close\r\nContent-Length: " + std::to_string(text.size()) +
           "\r\n" + headers + "\r\n" + text;
}

inline void send_best_effort(int fd, const std::string& data) {
    size_t off = 0;
    while (off < data.size()) {
        const ssize_t n = ::send(fd, data.data() + off, data.size() - off, MSG_NOSIGNAL | MSG_DONTWAIT);
        if (n <= 0) return;
        off += size_t(n);
    }
}

// Whether the client is still there: not hung up, not shut down its side.
inline bool peer_alive(int fd) {
    pollfd p{fd, short(POLLIN | POLLRDHUP), 0};
    if (::poll(&p, 1, 0) < 0) return errno == EINTR;
    if (p.revents & (POLLERR | POLLHUP | POLLRDHUP | POLLNVAL)) return false;
    if (p.revents & POLLIN) {
        char c;
        const ssize_t n = ::recv(fd, &c, 1, MSG_PEEK | MSG_DONTWAIT);
        if (n == 0) return false;
        if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) return false;
    }
    return true;
}

inline void address_of(const sockaddr_storage& sa, std::string& ip, int& port) {
    char text[INET6_ADDRSTRLEN] = "";
    if (sa.ss_family == AF_INET) {
        const auto* in = reinterpret_cast<const sockaddr_in*>(&sa);
        inet_ntop(AF_INET, &in->sin_addr, text, sizeof text);
        port = ntohs(in->sin_port);
    } else if (sa.ss_family == AF_INET6) {
        const auto* in6 = reinterpret_cast<const sockaddr_in6*>(&sa);
        inet_ntop(AF_INET6, &in6->sin6_addr, text, sizeof text);
        port = ntohs(in6->sin6_port);
    }
    ip = text;
}

// The value of header `name` (case-insensitive, as HTTP header names are)
// in `head`, a request line and its header lines, exactly as cpp-httplib
// reads the same bytes, so that the gate and the service never disagree on
// what a request says (issue #55: a bare-LF "Content-Length: 0" line before
// the real one made the gate count no body, while httplib read one):
// only a line that ends in CRLF is a header line (httplib skips one that
// ends in a bare LF, an empty one included), the headers end at the first
// empty CRLF line, the name runs to the first ':', the value is trimmed of
// spaces and tabs and percent-decoded (httplib decodes header values), and
// a header with an empty value is not there. The first if repeated. Empty
// when absent.
inline std::string header_value(std::string_view head, std::string_view name) {
    auto same = [](std::string_view a, std::string_view b) {
        return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
                   return std::tolower(static_cast<unsigned char>(x)) == std::tolower(static_cast<unsigned char>(y));
               });
    };
    for (size_t at = head.find('\n'); at != std::string_view::npos && at + 1 < head.size();) {
        const size_t begin = at + 1;
        at = head.find('\n', begin);
        if (at == std::string_view::npos) break;  // not a whole line
        std::string_view line = head.substr(begin, at - begin);
        if (line.empty() || line.back() != '\r') continue;  // a bare LF: httplib skips the line
        line.remove_suffix(1);
        if (line.empty()) break;  // the end of the headers
        const size_t colon = line.find(':');
        if (colon == std::string_view::npos || !same(line.substr(0, colon), name)) continue;
        line.remove_prefix(colon + 1);
        const size_t first = line.find_first_not_of(" \t"), last = line.find_last_not_of(" \t");
        if (first == std::string_view::npos) continue;  // an empty value: httplib keeps no such header
        return httplib::detail::decode_url(std::string(line.substr(first, last - first + 1)), false);
    }
    return {};
}

// Whether a request (its line and headers) comes with a body: a
// Content-Length other than 0, or a Transfer-Encoding. A malformed length
// counts as a body; httplib refuses it.
inline bool has_body(std::string_view head) {
    const std::string length = header_value(head, "Content-Length");
    return length.find_first_not_of('0') != std::string::npos || !header_value(head, "Transfer-Encoding").empty();
}

// The bearer token a request names, as the service reads it (decoded, as
// httplib decodes the header): the identity the per-token budgets are kept
// on is the one the service authenticates, so one token spelt 48 ways
// (percent-escapes) is one token (issue #55). Empty when none.
inline std::string bearer_token(std::string_view head) {
    const std::string auth = header_value(head, "Authorization");
    return auth.rfind("Bearer ", 0) == 0 ? auth.substr(7) : std::string();
}

// Whether the client has sent something the gate has not read yet (or
// closed its side): it is not idle, whatever the gate last saw.
inline bool has_input(int fd) {
    char c;
    const ssize_t n = ::recv(fd, &c, 1, MSG_PEEK | MSG_DONTWAIT);
    return n >= 0 || (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR);
}

class InlineQueue : public httplib::TaskQueue {
public:
    void enqueue(std::function<void()> fn) override { fn(); }
    void shutdown() override {}
};

}  // namespace gate

using gate::RequestContext;
using gate::tl_request;

class GatedServer : public httplib::Server {
    using Clock = gate::Clock;

public:
    GatedServer(const ServerLimits& limits, int threads, Metrics& metrics)
        : limits_(limits), threads_(threads), metrics_(metrics) {
        new_task_queue = [] { return new gate::InlineQueue; };
        set_keep_alive_timeout(time_t(std::max(1.0, limits.keep_alive_seconds)));
        set_keep_alive_max_count(gate::kMaxRequestsPerConnection);
    }
    ~GatedServer() override { stop_gate(); }

    // Before listen_after_bind(), and after it returned.
    void start_gate() {
        epoll_ = ::epoll_create1(EPOLL_CLOEXEC);
        if (epoll_ < 0) throw std::runtime_error(std::string("epoll_create1: ") + strerror(errno));
        // stop_gate() wakes the gate through this, rather than waiting out
        // its 100 ms tick (each stop of lightfarmd took that long).
        wake_ = ::eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
        if (wake_ < 0) throw std::runtime_error(std::string("eventfd: ") + strerror(errno));
        epoll_event wake{};
        wake.events = EPOLLIN;
        wake.data.fd = wake_;
        ::epoll_ctl(epoll_, EPOLL_CTL_ADD, wake_, &wake);
        pool_ = std::make_unique<httplib::ThreadPool>(size_t(threads_));
        gate_ = std::thread([this] { gate_loop(); });
    }
    // From a stop: requests in flight have `seconds` more to read and write,
    // then their reads and writes fail (a slow upload held SIGTERM for 32 s).
    // A second stop keeps the first one's deadline: each repeated stop
    // pushed it on, and an upload in flight held SIGTERM for 299 s (issue #55).
    void drain_within(double seconds) {
        const int64_t deadline =
            std::chrono::duration_cast<std::chrono::nanoseconds>(
                (Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds)))
                    .time_since_epoch())
                .count();
        int64_t current = drain_deadline_ns_.load();
        while (deadline < current && !drain_deadline_ns_.compare_exchange_weak(current, deadline)) {
        }
    }
    void stop_gate() {
        {
            std::lock_guard lock(mutex_);
            if (stopping_ || !gate_.joinable()) return;
            stopping_ = true;
        }
        const uint64_t one = 1;
        (void)!::write(wake_, &one, sizeof one);
        gate_.join();
        {
            std::lock_guard lock(mutex_);
            for (auto& [fd, c] : waiting_) close_locked(*c);
            waiting_.clear();
        }
        pool_->shutdown();  // request threads end: event streams see the service stopping
        ::close(epoll_);
        ::close(wake_);
    }

private:
    struct Conn {
        int fd = -1;
        std::string ip, local_ip;
        int port = 0, local_port = 0;
        std::string buf;             // read, not yet consumed
        Clock::time_point started;   // the request began (accept, or its first byte)
        Clock::time_point deadline;  // headers (or, draining, the linger) end by then
        bool got_bytes = false;
        bool draining = false;  // answered and shut down: reading only to close cleanly
        bool counted = false;   // holds a place in the connection caps
        int served = 0;
        size_t drained = 0;
        bool reading_body = false;  // holds a place in the body-read budgets (of `token` and `ip`)
        std::string token;

        // Idle: in the gate, counted, and not a byte of a request since it
        // connected or its last answer. The first to go at a cap.
        bool idle() const { return counted && !draining && !got_bytes; }
    };

    // A request's body, read on a request thread: first what the gate read
    // past the headers, then the socket, under the request's deadline and
    // within its byte budget.
    class GateStream : public httplib::Stream {
    public:
        GateStream(Conn& c, Clock::time_point deadline, uint64_t budget, RequestContext& ctx,
                   const std::atomic<int64_t>& drain_deadline_ns)
            : c_(c), deadline_(deadline), budget_(budget), ctx_(ctx), drain_deadline_ns_(drain_deadline_ns) {}
        bool is_readable() const override {
            if (pos_ < c_.buf.size()) return true;
            pollfd p{c_.fd, POLLIN, 0};
            return ::poll(&p, 1, remaining_ms()) > 0;
        }
        bool is_writable() const override { return !failed_ && gate::peer_alive(c_.fd); }
        ssize_t read(char* ptr, size_t size) override {
            if (pos_ >= c_.buf.size() && !refill()) return failed_ ? -1 : 0;
            const size_t n = std::min(size, c_.buf.size() - pos_);
            std::memcpy(ptr, c_.buf.data() + pos_, n);
            pos_ += n;
            return ssize_t(n);
        }
        ssize_t write(const char* ptr, size_t size) override {
            size_t off = 0;
            while (!failed_ && off < size) {
                if (drained()) {
                    failed_ = true;
                    break;
                }
                const ssize_t n = ::send(c_.fd, ptr + off, size - off, MSG_NOSIGNAL | MSG_DONTWAIT);
                if (n > 0) {
                    off += size_t(n);
                } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK)) {
                    pollfd p{c_.fd, POLLOUT, 0};
                    if (::poll(&p, 1, gate::kWriteTimeoutMs) <= 0) failed_ = true;  // a client that stopped reading
                } else if (!(n < 0 && errno == EINTR)) {
                    failed_ = true;
                }
            }
            return failed_ ? -1 : ssize_t(size);
        }
        void get_remote_ip_and_port(std::string& ip, int& port) const override { ip = c_.ip, port = c_.port; }
        void get_local_ip_and_port(std::string& ip, int& port) const override {
            ip = c_.local_ip, port = c_.local_port;
        }
        socket_t socket() const override { return c_.fd; }

        bool failed() const { return failed_; }
        // What was read past this request: the start of the next one.
        void keep_leftover() {
            c_.buf.erase(0, pos_);
            pos_ = 0;
        }

    private:
        // The server stopped and its drain ended (GatedServer::drain_within).
        bool drained() const { return Clock::now().time_since_epoch().count() >= drain_deadline(); }
        int64_t drain_deadline() const {
            return std::chrono::duration_cast<Clock::duration>(std::chrono::nanoseconds(drain_deadline_ns_.load()))
                .count();
        }
        int remaining_ms() const {
            const Clock::time_point drain{Clock::duration(drain_deadline())};
            const auto left =
                std::chrono::duration_cast<std::chrono::milliseconds>(std::min(deadline_, drain) - Clock::now())
                    .count();
            return int(std::clamp<int64_t>(left, 0, 1 << 30));
        }
        bool refill() {
            if (read_ >= budget_) {
                ctx_.over_budget = failed_ = true;
                return false;
            }
            c_.buf.erase(0, pos_);
            pos_ = 0;
            for (;;) {
                const int ms = remaining_ms();
                pollfd p{c_.fd, POLLIN, 0};
                const int ready = ms > 0 ? ::poll(&p, 1, ms) : 0;
                if (ready == 0) {
                    ctx_.timed_out = failed_ = true;
                    return false;
                }
                if (ready < 0) {
                    if (errno == EINTR) continue;
                    failed_ = true;
                    return false;
                }
                char tmp[64 * 1024];
                const ssize_t n = ::recv(c_.fd, tmp, size_t(std::min<uint64_t>(sizeof tmp, budget_ - read_ + 1)), 0);
                if (n > 0) {
                    c_.buf.append(tmp, size_t(n));
                    read_ += uint64_t(n);
                    return true;
                }
                if (n == 0) return false;  // the client closed
                if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
                    failed_ = true;
                    return false;
                }
            }
        }

        Conn& c_;
        Clock::time_point deadline_;
        uint64_t budget_;
        RequestContext& ctx_;
        const std::atomic<int64_t>& drain_deadline_ns_;
        size_t pos_ = 0;
        uint64_t read_ = 0;
        bool failed_ = false;
    };

    bool process_and_close_socket(socket_t sock) override {
        auto c = std::make_unique<Conn>();
        c->fd = int(sock);
        sockaddr_storage sa{};
        socklen_t len = sizeof sa;
        if (::getpeername(c->fd, reinterpret_cast<sockaddr*>(&sa), &len) == 0) gate::address_of(sa, c->ip, c->port);
        len = sizeof sa;
        if (::getsockname(c->fd, reinterpret_cast<sockaddr*>(&sa), &len) == 0)
            gate::address_of(sa, c->local_ip, c->local_port);
        ::fcntl(c->fd, F_SETFL, ::fcntl(c->fd, F_GETFL) | O_NONBLOCK);

        std::lock_guard lock(mutex_);
        if (stopping_) {
            ::close(c->fd);
            return true;
        }
        if (!make_room_locked(c->ip)) {
            refuse_connection_locked(std::move(c));
            return true;
        }
        c->counted = true;
        ++open_;
        ++by_address_[c->ip];
        ++metrics_.http_connections;
        c->started = Clock::now();
        c->deadline = c->started + seconds(limits_.header_seconds);
        add_waiting_locked(std::move(c));
        return true;
    }

    static int count_of(const std::map<std::string, int>& counts, const std::string& key) {
        const auto it = counts.find(key);
        return it == counts.end() ? 0 : it->second;
    }
    int connections_from_locked(const std::string& ip) const { return count_of(by_address_, ip); }

    // Idle connections go first: a new connection from `ip` that meets a cap
    // closes the oldest idle connection of its own address (at the
    // per-address cap) or of the address holding the most (at the total
    // cap), so that sockets which send nothing never lock anyone else out.
    // False when a cap is met and no connection is idle.
    bool make_room_locked(const std::string& ip) {
        for (;;) {
            const bool address_full = connections_from_locked(ip) >= limits_.connections_per_address;
            if (!address_full && open_ < limits_.connections) return true;
            Conn* idle = idle_to_drop_locked(address_full ? &ip : nullptr);
            if (!idle) return false;
            if (gate::has_input(idle->fd)) {
                on_readable_locked(*idle);  // it has just sent something, or left: look again
                continue;
            }
            ++metrics_.http_idle_dropped;
            finish_locked(idle->fd);
        }
    }

    // The idle connection to close for a new one: of `ip` if given, else of
    // the address holding the most connections (that has an idle one); the
    // one idle the longest. Null when none is idle. A scan of the gate's
    // connections (at most `connections`), only when a cap is met.
    Conn* idle_to_drop_locked(const std::string* ip) {
        Conn* pick = nullptr;
        int pick_held = 0;
        for (auto& [fd, conn] : waiting_) {
            Conn& c = *conn;
            if (!c.idle() || (ip && c.ip != *ip)) continue;
            const int held = ip ? 0 : connections_from_locked(c.ip);
            if (!pick || held > pick_held || (held == pick_held && c.started < pick->started)) {
                pick = &c;
                pick_held = held;
            }
        }
        return pick;
    }

    // 503 to a connection over a cap with nothing idle to close for it.
    void refuse_connection_locked(std::unique_ptr<Conn> c) {
        const bool address_full = connections_from_locked(c->ip) >= limits_.connections_per_address;
        const char* reason = address_full ? "connections_per_address" : "connections";
        const int limit = address_full ? limits_.connections_per_address : limits_.connections;
        metrics_.count_refusal(reason);
        gate::send_best_effort(
            c->fd, gate::canned_response(503, "Service Unavailable",
                                         {{"error", std::string(reason) + ": too many open connections (the limit is " +
                                                        std::to_string(limit) + "); retry later"},
                                          {"field", reason},
                                          {"limit", limit}},
                                         "Retry-After: 1\r\n"));
        if (uncounted_lingering_ >= gate::kMaxUncountedLingering) {
            ::close(c->fd);
            return;
        }
        ++uncounted_lingering_;
        start_linger_locked(std::move(c), true);
    }

    static Clock::duration seconds(double s) {
        return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
    }

    void add_waiting_locked(std::unique_ptr<Conn> c) {
        const int fd = c->fd;
        if (!c->draining) ++metrics_.http_reading_headers;
        Conn& ref = *c;
        waiting_[fd] = std::move(c);
        epoll_event ev{};
        ev.events = EPOLLIN | EPOLLRDHUP;
        ev.data.fd = fd;
        if (::epoll_ctl(epoll_, EPOLL_CTL_ADD, fd, &ev) != 0) {
            finish_locked(fd);
            return;
        }
        if (!ref.draining && !ref.buf.empty()) check_headers_locked(ref);  // a pipelined request
    }

    // Closes a connection that the gate holds (and forgets it).
    void finish_locked(int fd) {
        auto it = waiting_.find(fd);
        if (it == waiting_.end()) return;
        std::unique_ptr<Conn> c = std::move(it->second);
        waiting_.erase(it);
        ::epoll_ctl(epoll_, EPOLL_CTL_DEL, fd, nullptr);
        if (!c->draining) --metrics_.http_reading_headers;
        close_locked(*c);
    }

    void close_locked(Conn& c) {
        ::close(c.fd);
        if (c.counted) {
            --open_;
            if (--by_address_[c.ip] <= 0) by_address_.erase(c.ip);
            --metrics_.http_connections;
        } else if (c.draining) {
            --uncounted_lingering_;
        }
        c.fd = -1;
    }

    // After an answer that leaves the request's body unread: shut our side
    // down and read (discarding, bounded) until the client closes, so that
    // it gets the answer rather than a reset.
    void start_linger_locked(std::unique_ptr<Conn> c, bool new_entry) {
        (void)new_entry;
        ::shutdown(c->fd, SHUT_WR);
        c->draining = true;
        c->buf.clear();
        c->deadline = Clock::now() + gate::kLinger;
        add_waiting_locked(std::move(c));
    }

    // Answers a request in the gate (its body, if any, unread) and lingers.
    void refuse_locked(Conn& c, int status, const char* reason, const json& body, const std::string& headers = "") {
        metrics_.count_refusal(body.value("field", ""));
        gate::send_best_effort(c.fd, gate::canned_response(status, reason, body, headers));
        const int fd = c.fd;
        std::unique_ptr<Conn> owned = std::move(waiting_[fd]);
        waiting_.erase(fd);
        ::epoll_ctl(epoll_, EPOLL_CTL_DEL, fd, nullptr);
        --metrics_.http_reading_headers;
        start_linger_locked(std::move(owned), false);
    }

    void check_headers_locked(Conn& c) {
        const size_t line_end = c.buf.find('\n');
        if ((line_end == std::string::npos ? c.buf.size() : line_end) > gate::kRequestLineMax) {
            refuse_locked(c, 414, "URI Too Long",
                          {{"error", "the request line exceeds " + std::to_string(gate::kRequestLineMax) + " bytes"},
                           {"field", "request_line"}});
            return;
        }
        const size_t end = c.buf.find("\r\n\r\n");
        const size_t header_bytes = size_t(limits_.header_bytes);
        if (end == std::string::npos ? c.buf.size() > header_bytes : end + 4 > header_bytes) {
            refuse_locked(c, 431, "Request Header Fields Too Large",
                          {{"error", "the request line and headers exceed " + std::to_string(header_bytes) + " bytes"},
                           {"field", "header_bytes"}});
            return;
        }
        if (end == std::string::npos) return;
        // Whole: to a request thread, if its body (when it has one) fits the budgets.
        const std::string_view head(c.buf.data(), end + 4);
        if (gate::has_body(head) && !start_body_read_locked(c, gate::bearer_token(head))) return;
        const int fd = c.fd;
        std::unique_ptr<Conn> owned = std::move(waiting_[fd]);
        waiting_.erase(fd);
        ::epoll_ctl(epoll_, EPOLL_CTL_DEL, fd, nullptr);
        --metrics_.http_reading_headers;
        Conn* raw = owned.release();
        pool_->enqueue([this, raw] { serve(std::unique_ptr<Conn>(raw)); });
    }

    // A body is read on a request thread for as long as its client takes:
    // one token, or one address, may have only so many read at once, so
    // that one tenant's slow bodies take only its own share of the threads;
    // all of them together at most body_reads (half the threads; a token's
    // first body aside), and with the event streams open no more than
    // threads_for_bodies_and_streams,
    // so that many tenants together cannot hold every thread either.
    // Beyond, 503 before the body is read. False when refused.
    bool start_body_read_locked(Conn& c, std::string token) {
        const char* field = nullptr;
        int limit = 0;
        std::string why;
        const int streams = int(metrics_.event_streams.load());
        const int shared = threads_for_bodies_and_streams(threads_);
        if (!token.empty() && count_of(body_reads_by_token_, token) >= limits_.body_reads_per_token)
            field = "body_reads_per_token", limit = limits_.body_reads_per_token;
        else if (count_of(body_reads_by_address_, c.ip) >= limits_.body_reads_per_address)
            field = "body_reads_per_address", limit = limits_.body_reads_per_address;
        // A token with no body being read gets one beyond the total (within
        // the three quarters): others' slow bodies do not refuse its upload.
        else if (body_reads_ >= limits_.body_reads && (token.empty() || count_of(body_reads_by_token_, token) > 0))
            field = "body_reads", limit = limits_.body_reads;
        else if (body_reads_ + streams >= shared)
            field = "body_reads", limit = std::max(0, shared - streams),
            why = "body_reads: request bodies being read (" + std::to_string(body_reads_) + ") and event streams (" +
                  std::to_string(streams) + ") hold " + std::to_string(shared) + " of the " + std::to_string(threads_) +
                  " request threads, the most they may together; retry later";
        if (field) {
            if (why.empty())
                why = std::string(field) + ": " + std::to_string(limit) +
                      " request bodies are being read already; retry later";
            refuse_locked(c, 503, "Service Unavailable", {{"error", why}, {"field", field}, {"limit", limit}},
                          "Retry-After: 1\r\n");
            return false;
        }
        ++body_reads_;
        if (!token.empty()) ++body_reads_by_token_[token];
        ++body_reads_by_address_[c.ip];
        ++metrics_.http_body_reads;
        c.reading_body = true;
        c.token = std::move(token);
        return true;
    }

    void end_body_read_locked(Conn& c) {
        if (!c.reading_body) return;
        --body_reads_;
        if (!c.token.empty() && --body_reads_by_token_[c.token] <= 0) body_reads_by_token_.erase(c.token);
        if (--body_reads_by_address_[c.ip] <= 0) body_reads_by_address_.erase(c.ip);
        --metrics_.http_body_reads;
        c.reading_body = false;
        c.token.clear();
    }

    void on_readable_locked(Conn& c) {
        char tmp[16 * 1024];
        for (;;) {
            const size_t room =
                c.draining ? sizeof tmp
                           : std::min(sizeof tmp, size_t(limits_.header_bytes) + 1 -
                                                      std::min(c.buf.size(), size_t(limits_.header_bytes) + 1));
            if (room == 0) break;
            const ssize_t n = ::recv(c.fd, tmp, room, 0);
            if (n > 0) {
                if (c.draining) {
                    c.drained += size_t(n);
                    if (c.drained > gate::kLingerBytes) return finish_locked(c.fd);
                    continue;
                }
                if (!c.got_bytes) {
                    c.got_bytes = true;
                    if (c.served > 0) {  // a kept-alive connection's next request starts now
                        c.started = Clock::now();
                        c.deadline = c.started + seconds(limits_.header_seconds);
                    }
                }
                c.buf.append(tmp, size_t(n));
                continue;
            }
            if (n == 0) {
                // The client closed its side; a whole request it sent before is still answered.
                if (!c.draining && c.buf.find("\r\n\r\n") != std::string::npos) return check_headers_locked(c);
                return finish_locked(c.fd);
            }
            if (errno == EINTR) continue;
            if (errno == EAGAIN || errno == EWOULDBLOCK) break;
            return finish_locked(c.fd);
        }
        if (!c.draining) check_headers_locked(c);
    }

    void gate_loop() {
        std::vector<epoll_event> events(256);
        for (;;) {
            const int n = ::epoll_wait(epoll_, events.data(), int(events.size()), 100);
            std::lock_guard lock(mutex_);
            if (stopping_) return;
            for (int i = 0; i < n; ++i) {
                auto it = waiting_.find(events[size_t(i)].data.fd);
                if (it != waiting_.end()) on_readable_locked(*it->second);
            }
            const Clock::time_point now = Clock::now();
            std::vector<int> expired;
            for (const auto& [fd, c] : waiting_)
                if (now >= c->deadline) expired.push_back(fd);
            for (int fd : expired) {
                auto it = waiting_.find(fd);
                if (it == waiting_.end()) continue;
                Conn& c = *it->second;
                if (c.draining || !c.got_bytes) {
                    finish_locked(fd);  // lingered long enough, or an idle kept-alive connection
                } else {
                    refuse_locked(c, 408, "Request Timeout",
                                  {{"error", "the request line and headers did not arrive within " +
                                                 json(limits_.header_seconds).dump() + " s"},
                                   {"field", "header_seconds"}});
                }
            }
        }
    }

    // On a request thread: one request, then back to the gate (kept alive)
    // or closed.
    void serve(std::unique_ptr<Conn> c) {
        RequestContext ctx;
        bool stopping;
        {
            std::lock_guard lock(mutex_);
            stopping = stopping_;
        }
        const bool close = stopping || c->served + 1 >= gate::kMaxRequestsPerConnection;
        bool closed = false;
        bool ok;
        {
            GateStream strm(*c, c->started + seconds(limits_.request_seconds),
                            limits_.upload_bytes + (1 << 20) + uint64_t(limits_.header_bytes), ctx, drain_deadline_ns_);
            tl_request = &ctx;
            ok = process_request(strm, close, closed, nullptr) && !strm.failed();
            tl_request = nullptr;
            strm.keep_leftover();
        }
        ++c->served;
        if (ctx.timed_out) metrics_.count_refusal("request_seconds");
        std::lock_guard lock(mutex_);
        end_body_read_locked(*c);
        if (stopping_) {
            close_locked(*c);
        } else if (ctx.close_after || ctx.timed_out || ctx.over_budget) {
            start_linger_locked(std::move(c), false);
        } else if (!ok || closed || close) {
            close_locked(*c);
        } else {
            c->got_bytes = !c->buf.empty();
            c->started = Clock::now();
            c->deadline = c->started + seconds(c->got_bytes ? limits_.header_seconds : limits_.keep_alive_seconds);
            add_waiting_locked(std::move(c));
        }
    }

    const ServerLimits limits_;
    const int threads_;
    Metrics& metrics_;
    std::unique_ptr<httplib::ThreadPool> pool_;
    std::thread gate_;
    int epoll_ = -1;
    int wake_ = -1;  // an eventfd: written once, by stop_gate()

    std::mutex mutex_;
    bool stopping_ = false;
    std::atomic<int64_t> drain_deadline_ns_{std::numeric_limits<int64_t>::max()};  // drain_within's, since the epoch
    std::map<int, std::unique_ptr<Conn>> waiting_;  // by fd: gathering headers, or lingering
    int open_ = 0;
    std::map<std::string, int> by_address_;  // counted connections
    int uncounted_lingering_ = 0;
    int body_reads_ = 0;                                                      // bodies being read
    std::map<std::string, int> body_reads_by_token_, body_reads_by_address_;  // of them, by token and by address
};

}  // namespace lf::server
