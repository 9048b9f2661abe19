// lightfarmd's HTTP layer against slow, idle, oversized and hostile clients
// (issue #15), on loopback with the fake engine: slow header senders and open
// event streams do not starve the API; requests are checked before their
// bodies are read and bounded in memory; a POST without a body is a POST;
// names are exactly what they say; a cache hit keeps tenants apart.
// Every loop here is bounded in count and in time.
#include "server_harness.h"

#include "http_gate.h"

#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <thread>

namespace lf::test {
namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

const std::vector<std::string> kTokens = {"http-alpha-0123456789", "http-beta-0123456789", "http-gamma-0123456789",
                                          "http-delta-0123456789", "http-epsilon-0123456789"};
const std::string& kAlice = kTokens[0];
const std::string& kBob = kTokens[1];

std::string glb(const std::string& tag) { return std::string("glTF\x02\x00\x00\x00", 8) + " " + tag; }

double seconds_since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// A raw loopback connection, for what an HTTP client library will not send.
class RawSocket {
public:
    // From `source` when given: any 127/8 address reaches the server on
    // loopback, so one test can be several client addresses.
    explicit RawSocket(int port, const char* source = nullptr) {
        fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (source) {
            sockaddr_in from{};
            from.sin_family = AF_INET;
            ::inet_pton(AF_INET, source, &from.sin_addr);
            if (::bind(fd_, reinterpret_cast<sockaddr*>(&from), sizeof from) != 0) return;
        }
        sockaddr_in a{};
        a.sin_family = AF_INET;
        a.sin_port = htons(uint16_t(port));
        a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
        connected_ = ::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
    }
    ~RawSocket() { close(); }
    RawSocket(const RawSocket&) = delete;
    RawSocket& operator=(const RawSocket&) = delete;
    bool connected() const { return connected_; }
    void close() {
        if (fd_ >= 0) ::close(fd_);
        fd_ = -1;
    }
    // Sends all of `data` unless the peer stops it; returns the bytes sent.
    size_t send(const std::string& data) {
        size_t off = 0;
        while (fd_ >= 0 && off < data.size()) {
            pollfd p{fd_, POLLOUT, 0};
            if (::poll(&p, 1, 2000) <= 0) break;
            const ssize_t n = ::send(fd_, data.data() + off, data.size() - off, MSG_NOSIGNAL | MSG_DONTWAIT);
            if (n < 0 && (errno == EAGAIN || errno == EINTR)) continue;
            if (n <= 0) break;
            off += size_t(n);
        }
        return off;
    }
    // Reads until `until` appears, the peer closes, or `timeout`.
    std::string read(const std::string& until, std::chrono::milliseconds timeout = 3s) {
        const auto deadline = Clock::now() + timeout;
        while (fd_ >= 0 && (until.empty() || in_.find(until) == std::string::npos)) {
            const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count();
            if (left <= 0) break;
            pollfd p{fd_, POLLIN, 0};
            if (::poll(&p, 1, int(left)) <= 0) break;
            char buf[16384];
            const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
            if (n <= 0) break;
            in_.append(buf, size_t(n));
        }
        return in_;
    }
    // The status code of the answer read so far (0 when none).
    int status() {
        read("\r\n\r\n");
        if (in_.rfind("HTTP/1.1 ", 0) != 0 || in_.size() < 12) return 0;
        return std::atoi(in_.c_str() + 9);
    }
    std::string received() const { return in_; }
    bool peer_closed(std::chrono::milliseconds timeout) {
        pollfd p{fd_, POLLIN, 0};
        const auto deadline = Clock::now() + timeout;
        while (Clock::now() < deadline) {
            if (::poll(&p, 1, 50) > 0) {
                char buf[4096];
                const ssize_t n = ::recv(fd_, buf, sizeof buf, 0);
                if (n <= 0) return true;
                in_.append(buf, size_t(n));
            }
        }
        return false;
    }
    // Whether the server has closed this connection by now (without waiting).
    bool closed_now() {
        pollfd p{fd_, POLLIN, 0};
        if (::poll(&p, 1, 0) <= 0) return false;
        char c;
        return ::recv(fd_, &c, 1, MSG_PEEK | MSG_DONTWAIT) == 0;
    }

private:
    int fd_ = -1;
    bool connected_ = false;
    std::string in_;
};

// An upload in flight: `head` sent, then 1 KiB every `period` (at most 120
// times) from a thread of its own until stop().
class TricklingUpload {
public:
    TricklingUpload(int port, const std::string& head, std::chrono::milliseconds period) : socket_(port) {
        socket_.send(head);
        trickle_ = std::thread([this, period] {
            for (int i = 0; i < 120 && trickling_; ++i) {
                socket_.send(std::string(1024, 'x'));
                std::this_thread::sleep_for(period);
            }
        });
    }
    ~TricklingUpload() { stop(); }
    bool connected() const { return socket_.connected(); }
    void stop() {
        trickling_ = false;
        if (trickle_.joinable()) trickle_.join();
    }

private:
    RawSocket socket_;
    std::atomic<bool> trickling_{true};
    std::thread trickle_;
};

// How many of `sockets` are answered within `wait` with a 503 that names
// `field` (with Retry-After); the others are still sending their bodies.
int refused_naming(std::vector<std::unique_ptr<RawSocket>>& sockets, const std::string& field,
                   std::chrono::milliseconds wait) {
    int refused = 0;
    const auto deadline = Clock::now() + wait;
    for (auto& s : sockets) {
        const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
        s->read("\n}\n", std::max<std::chrono::milliseconds>(left, 20ms));
        if (s->received().empty()) continue;
        EXPECT_EQ(s->status(), 503) << s->received();
        EXPECT_NE(s->received().find("Retry-After: 1"), std::string::npos) << s->received();
        EXPECT_NE(s->received().find("\"field\": \"" + field + "\""), std::string::npos) << s->received();
        ++refused;
    }
    return refused;
}

// kB from /proc/PID/status.
long proc_status_kb(pid_t pid, const std::string& key) {
    std::ifstream in("/proc/" + std::to_string(pid) + "/status");
    for (std::string line; std::getline(in, line);)
        if (line.rfind(key + ":", 0) == 0) return std::atol(line.c_str() + key.size() + 1);
    return -1;
}

// The sockets a process holds (/proc/PID/fd): how a test knows that the
// server has accepted the connections it opened, without opening another.
int open_sockets(pid_t pid) {
    int n = 0;
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator("/proc/" + std::to_string(pid) + "/fd", ec)) {
        const fs::path target = fs::read_symlink(entry.path(), ec);
        if (!ec && target.string().rfind("socket:", 0) == 0) ++n;
    }
    return n;
}

// Waits (at most `timeout`) until the server holds `n` connections: sockets
// besides its listening one. A loaded machine may take a while to accept
// them (a fixed second was not always enough under ctest -j2).
testing::AssertionResult server_holds_connections(pid_t pid, int n, std::chrono::milliseconds timeout = 10s) {
    const auto deadline = Clock::now() + timeout;
    int held = 0;
    while ((held = open_sockets(pid) - 1) < n) {
        if (Clock::now() >= deadline)
            return testing::AssertionFailure() << "the server holds " << held << " connections, not " << n;
        std::this_thread::sleep_for(20ms);
    }
    return testing::AssertionSuccess();
}

// Waits (at most 5 s) until the server holds no connection: the harness's
// own /healthz at start may still hold a place, and at a cap it would
// make an idle socket of the test's go before it.
testing::AssertionResult server_holds_no_connection(pid_t pid) {
    const auto deadline = Clock::now() + 5s;
    while (open_sockets(pid) > 1) {
        if (Clock::now() >= deadline)
            return testing::AssertionFailure() << "the server still holds " << open_sockets(pid) - 1 << " connections";
        std::this_thread::sleep_for(20ms);
    }
    return testing::AssertionSuccess();
}

class HttpTest : public ::testing::Test {
protected:
    TempDir tmp;
    FakeEngine engine{tmp.path / "engine"};
    std::unique_ptr<Lightfarmd> server;

    void start(std::vector<std::string> extra = {}) {
        std::string text;
        for (const std::string& t : kTokens) text += t + "\n";
        write_text(tmp.path / "tokens", text);
        extra.insert(extra.end(), {"--workers", "1"});
        server = std::make_unique<Lightfarmd>(tmp.path / "data", tmp.path / "tokens", engine.script, std::move(extra));
        server->start();
    }
    void TearDown() override {
        if (HasFailure() && server) std::cerr << "---- lightfarmd log ----\n" << server->log();
    }
    httplib::Client client(const std::string& token = kAlice) { return server->client(token); }
    std::string upload(const std::string& token, const std::string& tag) {
        auto r = client(token).Post("/v1/scenes", glb(tag), "model/gltf-binary");
        EXPECT_TRUE(r && (r->status == 201 || r->status == 200)) << (r ? r->body : "no answer");
        return r ? json::parse(r->body).value("id", "") : "";
    }
    httplib::Result post_job(const std::string& scene, int passes, int seed, const std::string& token = kAlice) {
        const json spec = {{"scene", scene}, {"seed", seed}, {"outputs", {{"lightmap", {{"passes", passes}}}}}};
        return client(token).Post("/v1/jobs", spec.dump(), "application/json");
    }
    std::string submit(const std::string& scene, int passes, int seed, const std::string& token = kAlice) {
        auto r = post_job(scene, passes, seed, token);
        EXPECT_TRUE(r && r->status == 201) << (r ? r->body : "no answer");
        return r ? json::parse(r->body).value("id", "") : "";
    }
    std::string request(const std::string& method, const std::string& path, const std::string& token,
                        const std::string& more_headers = "") {
        return method + " " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\n" +
               (token.empty() ? "" : "Authorization: Bearer " + token + "\r\n") + more_headers + "\r\n";
    }
    // lightfarmd with request_seconds 60 and drain_seconds 1, and a 64 MiB
    // upload trickling in (TricklingUpload), being read on a request thread.
    std::unique_ptr<TricklingUpload> upload_in_flight(std::chrono::milliseconds period) {
        start({"--limit", "request_seconds=60", "--limit", "drain_seconds=1"});
        auto upload = std::make_unique<TricklingUpload>(
            server->port,
            request("POST", "/v1/scenes?name=slow.glb", kAlice,
                    "Content-Type: model/gltf-binary\r\nContent-Length: 67108864\r\n") +
                glb("slow"),
            period);
        EXPECT_TRUE(upload->connected());
        std::this_thread::sleep_for(1500ms);
        return upload;
    }
    double metric(const std::string& name) {
        auto r = client().Get("/metrics");
        if (!r) return -1;
        const size_t at = r->body.find("\n" + name + " ");
        return at == std::string::npos ? -1 : std::atof(r->body.c_str() + at + name.size() + 2);
    }
};

// With the defaults (64 threads: 32 streams) one token holds at most a
// quarter of the streams, so no two tokens can take them all (the per-token
// default of 16 let two). Other tokens' streams still open.
TEST_F(HttpTest, NoTwoTokensCanHoldEveryEventStream) {
    start();
    const std::string scene = upload(kAlice, "streams");
    engine.set("delay", "0.05");
    const std::string job = submit(scene, 400, 1);
    ASSERT_FALSE(job.empty());
    std::vector<std::unique_ptr<RawSocket>> streams;
    int accepted = 0;
    for (int i = 0; i < 20; ++i) {
        auto s = std::make_unique<RawSocket>(server->port);
        s->send(request("GET", "/v1/jobs/" + job + "/events", kAlice));
        if (s->status() == 200) ++accepted;
        streams.push_back(std::move(s));
    }
    EXPECT_EQ(accepted, 8) << "a quarter of the 32 streams";
    auto c = client();
    EXPECT_EQ(c.Get("/healthz")->status, 200);
}

// Nor can one address with many tokens (issue #33): by default an address
// holds at most half of the 32 streams, whatever its tokens; beyond, 503 +
// Retry-After naming event_streams_per_address, and another address's token
// still opens its streams.
TEST_F(HttpTest, NoOneAddressCanHoldEveryEventStreamWithManyTokens) {
    start();
    engine.set("delay", "0.05");
    std::map<std::string, std::string> jobs;  // token -> a job of its own, running or queued for a while
    for (const std::string& token : kTokens) {
        jobs[token] = submit(upload(token, "streams " + token), 400, 1, token);
        ASSERT_FALSE(jobs[token].empty());
    }
    std::vector<std::unique_ptr<RawSocket>> streams;
    int accepted = 0;
    for (size_t t = 0; t < 4; ++t) {  // four tokens from 127.0.0.1, 8 streams each (each under its own cap)
        for (int i = 0; i < 8; ++i) {
            auto s = std::make_unique<RawSocket>(server->port, "127.0.0.1");
            s->send(request("GET", "/v1/jobs/" + jobs[kTokens[t]] + "/events", kTokens[t]));
            const int status = s->status();
            if (status == 200) {
                ++accepted;
            } else {
                EXPECT_EQ(status, 503) << s->received();
                const std::string answer = s->read("}");
                EXPECT_NE(answer.find("Retry-After: 5"), std::string::npos) << answer;
                EXPECT_NE(answer.find("\"field\": \"event_streams_per_address\""), std::string::npos) << answer;
            }
            streams.push_back(std::move(s));
        }
    }
    EXPECT_EQ(accepted, 16) << "half of the 32 streams from one address";
    // Another address's token opens all its own.
    int others = 0;
    for (int i = 0; i < 8; ++i) {
        auto s = std::make_unique<RawSocket>(server->port, "127.0.0.2");
        s->send(request("GET", "/v1/jobs/" + jobs[kTokens[4]] + "/events", kTokens[4]));
        others += s->status() == 200;
        streams.push_back(std::move(s));
    }
    EXPECT_EQ(others, 8);
    EXPECT_EQ(metric("lightfarm_event_streams"), 24);
    EXPECT_EQ(client().Get("/healthz")->status, 200);
}

// The first test: 100 clients trickling header lines and 100 event
// streams (then vanishing) leave /healthz, GET /v1/jobs and a submission
// answering within 1 s, and the streams that remain get their events.
TEST_F(HttpTest, SlowClientsAndEventStreamsDoNotStarveTheApi) {
    start({"--limit", "header_seconds=4", "--limit", "event_streams_per_token=8"});
    engine.set("delay", "0.05");
    const std::string scene = upload(kAlice, "busy");
    const std::string job = submit(scene, 400, 1);  // ~20 s of progress events
    ASSERT_FALSE(job.empty());

    // 100 slow clients: a request line, then a header line now and then;
    // from four addresses, as one address may hold at most 64 connections.
    std::vector<std::unique_ptr<RawSocket>> slow;
    const char* const addresses[] = {"127.0.0.2", "127.0.0.3", "127.0.0.4", "127.0.0.5"};
    for (int i = 0; i < 100; ++i) {
        slow.push_back(std::make_unique<RawSocket>(server->port, addresses[i % 4]));
        ASSERT_TRUE(slow.back()->connected());
        slow.back()->send("GET /healthz HTTP/1.1\r\n");
    }
    std::atomic<bool> trickling{true};
    std::thread trickle([&] {
        for (int round = 0; round < 40 && trickling; ++round) {  // at most 40 x 250 ms
            for (auto& s : slow) s->send("X-Slow: " + std::to_string(round) + "\r\n");
            std::this_thread::sleep_for(250ms);
        }
    });

    // 100 event streams of the job from four tokens, all of them the owner's
    // (the job is Alice's: the others' are 404s, which must not count either).
    std::vector<std::unique_ptr<RawSocket>> streams;
    int accepted = 0, refused = 0;
    for (int i = 0; i < 100; ++i) {
        auto s = std::make_unique<RawSocket>(server->port);
        ASSERT_TRUE(s->connected());
        s->send(request("GET", "/v1/jobs/" + job + "/events", kAlice));
        const int status = s->status();
        if (status == 200) {
            ++accepted;
            streams.push_back(std::move(s));
        } else {
            ASSERT_EQ(status, 503) << s->received();
            EXPECT_NE(s->received().find("Retry-After:"), std::string::npos);
            ++refused;
        }
    }
    // One token holds at most event_streams_per_token (8) streams.
    EXPECT_EQ(accepted, 8);
    EXPECT_EQ(refused, 92);

    // The API answers within 1 s, while all of that is open.
    auto c = client();
    auto timed = [&](const std::string& what, const std::function<bool()>& call) {
        const auto t0 = Clock::now();
        EXPECT_TRUE(call()) << what;
        const double took = seconds_since(t0);
        std::cerr << what << " with 100 slow clients and " << accepted << " open streams: " << took * 1000 << " ms\n";
        EXPECT_LT(took, 1.0) << what;
    };
    timed("healthz", [&] {
        auto r = c.Get("/healthz");
        return r && r->status == 200;
    });
    timed("list jobs", [&] {
        auto r = c.Get("/v1/jobs");
        return r && r->status == 200;
    });
    timed("submit", [&] {
        auto r = post_job(scene, 2, 99);
        return r && r->status == 201;
    });
    // Other tokens still open their own streams.
    {
        RawSocket other(server->port);
        other.send(request("GET", "/v1/jobs/" + job + "/events", kBob));
        EXPECT_EQ(other.status(), 404);  // not Bob's job: and no stream slot taken
    }

    // Half the streams vanish; the others still get events, and the slots
    // come back for new streams within a few seconds.
    for (size_t i = 0; i < streams.size(); i += 2) streams[i]->close();
    for (size_t i = 1; i < streams.size(); i += 2) {
        const size_t before = streams[i]->received().size();
        streams[i]->read("event: progress");
        const std::string more = streams[i]->read("", 300ms);
        EXPECT_GT(more.size(), before) << "stream " << i << " got no events";
    }
    const auto deadline = Clock::now() + 5s;
    while (metric("lightfarm_event_streams") > 4 && Clock::now() < deadline) std::this_thread::sleep_for(50ms);
    EXPECT_EQ(metric("lightfarm_event_streams"), 4);
    RawSocket again(server->port);
    again.send(request("GET", "/v1/jobs/" + job + "/events", kAlice));
    EXPECT_EQ(again.status(), 200);

    // A slow client is answered 408 at the header deadline (4 s here) and closed.
    trickling = false;
    trickle.join();
    RawSocket late(server->port);
    late.send("GET /healthz HTTP/1.1\r\nX-Slow: 1\r\n");
    const auto t0 = Clock::now();
    EXPECT_EQ(late.status(), 0);  // nothing yet
    late.read("\r\n\r\n", 6s);
    EXPECT_EQ(late.status(), 408);
    EXPECT_LT(seconds_since(t0), 5.5);
    EXPECT_TRUE(late.peer_closed(2s));

    auto r = c.Post("/v1/jobs/" + job + "/cancel");
    EXPECT_TRUE(r && r->status == 200);
}

// Connections that have begun a request are not idle: they count, and over
// the per-address cap a new connection is answered 503 with Retry-After; an
// idle connection among them is closed for a new one instead (it used to
// be refused with the others). The API is back as soon as they close.
TEST_F(HttpTest, ConnectionCapsAnswer503) {
    start({"--limit", "connections_per_address=20"});
    ASSERT_TRUE(server_holds_no_connection(server->pid()));
    RawSocket idle(server->port);
    std::vector<std::unique_ptr<RawSocket>> busy;
    auto begin_request = [&] {
        busy.push_back(std::make_unique<RawSocket>(server->port));
        busy.back()->send("GET /healthz HTTP/1.1\r\n");
    };
    for (int i = 0; i < 19; ++i) begin_request();
    ASSERT_TRUE(server_holds_connections(server->pid(), 20));

    // At the cap: the idle connection goes, the new request is answered.
    RawSocket first(server->port);
    first.send(request("GET", "/healthz", "", "Connection: close\r\n"));
    EXPECT_EQ(first.status(), 200) << first.received();
    EXPECT_TRUE(idle.peer_closed(2s)) << "the idle connection was not closed for the new one";

    // Twenty connections that have each sent part of a request: a new one is refused.
    ASSERT_TRUE(first.peer_closed(2s));
    begin_request();
    ASSERT_TRUE(server_holds_connections(server->pid(), 20));
    RawSocket over(server->port);
    over.send(request("GET", "/healthz", ""));
    ASSERT_EQ(over.status(), 503) << over.received();
    over.peer_closed(2s);  // the whole answer: under load the body may follow the headers later
    EXPECT_NE(over.received().find("Retry-After: 1"), std::string::npos);
    EXPECT_NE(over.received().find("connections_per_address"), std::string::npos);
    busy.clear();
    const auto deadline = Clock::now() + 3s;
    int status = 0;
    while (status != 200 && Clock::now() < deadline) {
        auto r = client().Get("/healthz");
        status = r ? r->status : 0;
        if (status != 200) std::this_thread::sleep_for(50ms);
    }
    EXPECT_EQ(status, 200);
    // (Asked only now: the request for it would have taken a place.)
    EXPECT_EQ(metric("lightfarm_http_idle_dropped_total"), 1);
}

// Issue #33: 260 sockets from one address, opened and never written to,
// refused every other client on that address (503: the per-address cap was
// 256), and reconnecting ~50 times a second kept it so. Now the cap is 64
// by default and a new connection that meets it closes the oldest of its
// address's connections that has sent nothing: idle sockets cost only the
// client that holds them.
TEST_F(HttpTest, IdleSocketsDoNotLockOutTheirAddress) {
    start();
    std::vector<std::unique_ptr<RawSocket>> idle;
    for (int i = 0; i < 260; ++i) {
        idle.push_back(std::make_unique<RawSocket>(server->port));
        ASSERT_TRUE(idle.back()->connected()) << i;
    }
    // And one more idle socket every 20 ms while the API is asked.
    std::atomic<bool> churning{true};
    std::thread churn([&] {
        std::vector<std::unique_ptr<RawSocket>> mine;
        for (int i = 0; i < 250 && churning; ++i) {  // at most 250 x 20 ms
            mine.push_back(std::make_unique<RawSocket>(server->port));
            std::this_thread::sleep_for(20ms);
        }
    });
    for (int i = 0; i < 10; ++i) {
        const auto t0 = Clock::now();
        auto r = client().Get("/healthz");
        const double took = seconds_since(t0);
        ASSERT_TRUE(r) << "request " << i;
        EXPECT_EQ(r->status, 200) << r->body;
        EXPECT_LT(took, 1.0) << "request " << i;
    }
    churning = false;
    churn.join();
    EXPECT_TRUE(idle.front()->peer_closed(1s)) << "the oldest idle socket is the first to go";
    EXPECT_GE(metric("lightfarm_http_idle_dropped_total"), 260 - 64);
    EXPECT_LE(metric("lightfarm_http_connections"), 64);
}

// Issue #33: 2 x 256 idle sockets from two addresses refused everyone (the
// total cap, 512). At the total cap a new connection closes the oldest idle
// connection of the address holding the most, so a third address gets in
// and the hog pays, not the smaller client.
TEST_F(HttpTest, IdleSocketsFillingEveryPlaceDoNotRefuseAnotherAddress) {
    start({"--limit", "connections=100", "--limit", "connections_per_address=60"});
    ASSERT_TRUE(server_holds_no_connection(server->pid()));
    std::vector<std::unique_ptr<RawSocket>> hog, other;
    for (int i = 0; i < 60; ++i) {
        hog.push_back(std::make_unique<RawSocket>(server->port, "127.0.0.2"));
        ASSERT_TRUE(hog.back()->connected()) << i;
    }
    for (int i = 0; i < 40; ++i) {
        other.push_back(std::make_unique<RawSocket>(server->port, "127.0.0.3"));
        ASSERT_TRUE(other.back()->connected()) << i;
    }
    ASSERT_TRUE(server_holds_connections(server->pid(), 100)) << "every place taken";

    auto r = client().Get("/healthz");  // from 127.0.0.1
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 200) << r->body;
    EXPECT_TRUE(hog.front()->peer_closed(1s)) << "the hog's oldest idle socket is the first to go";
    EXPECT_FALSE(hog.back()->closed_now());
    for (size_t i = 0; i < other.size(); ++i) {
        EXPECT_FALSE(other[i]->closed_now()) << "the smaller client's socket " << i << " was closed";
    }
    EXPECT_GE(metric("lightfarm_http_idle_dropped_total"), 1);
}

// Issue #33: one tenant's 64 slow request bodies took all 64 request
// threads, and nothing else (/healthz included) was answered until they
// timed out. A body is read on a request thread, so the gate budgets them
// before a thread is taken: body_reads_per_token (an eighth of
// --http-threads: 8) and body_reads_per_address (a quarter: 16); beyond,
// 503 with Retry-After naming the limit, the body unread. The slow tenant
// uses 127.0.0.2; everyone else, 127.0.0.1.
TEST_F(HttpTest, OneTokensSlowBodiesDoNotStopTheApi) {
    // request_seconds 20: on a server without the budget the threads come back within it.
    // 73 connections from the slow tenant's address, over the per-address default of 64.
    start({"--limit", "request_seconds=20", "--limit", "connections_per_address=128"});
    const std::string& slow_token = kTokens[2];
    // A thousand bytes announced, ten sent. Header names are any case in
    // HTTP, and the gate reads them so: `lower_case` sends them that way.
    // And as the server reads them (issue #55): `disguise` k > 0 spells the
    // token with its (k - 1)th character percent-escaped (httplib decodes
    // header values: the same token to the service) and puts a bare-LF
    // "Content-Length: 0" line first (httplib skips a line without its CR).
    auto slow_upload = [&](const std::string& token, bool lower_case = false, size_t disguise = 0) {
        auto s = std::make_unique<RawSocket>(server->port, "127.0.0.2");
        std::string spelt = token;
        if (disguise > 0) {
            char escaped[4];
            std::snprintf(escaped, sizeof escaped, "%%%02X",
                          static_cast<unsigned char>(token[(disguise - 1) % token.size()]));
            spelt = token.substr(0, (disguise - 1) % token.size()) + escaped +
                    token.substr((disguise - 1) % token.size() + 1);
        }
        const std::string head = request("POST", "/v1/scenes", spelt,
                                         std::string(disguise > 0 ? "Content-Length: 0\n" : "") +
                                             "Content-Type: model/gltf-binary\r\nContent-Length: 1000\r\n");
        s->send((lower_case ? "POST /v1/scenes HTTP/1.1\r\nhost: 127.0.0.1\r\nauthorization: Bearer " + token +
                                  "\r\ncontent-type: model/gltf-binary\r\ncontent-length: 1000\r\n\r\n"
                            : head) +
                "0123456789");
        return s;
    };

    // Half of them disguised, each spelling another: one token, one budget.
    std::vector<std::unique_ptr<RawSocket>> slow;
    for (int i = 0; i < 64; ++i) slow.push_back(slow_upload(slow_token, false, i % 2 ? size_t(i / 2 + 1) : 0));
    EXPECT_EQ(refused_naming(slow, "body_reads_per_token", 2s), 64 - 8);
    // Another token from the same address: 8 more, and the address is at its
    // 16; a third token's body from there is refused.
    std::vector<std::unique_ptr<RawSocket>> second;
    for (int i = 0; i < 8; ++i) second.push_back(slow_upload(kTokens[3], true));
    second.push_back(slow_upload(kBob));
    EXPECT_EQ(refused_naming(second, "body_reads_per_address", 2s), 1);

    // Everyone else is answered at once.
    auto timed = [&](const std::string& what, const std::function<bool()>& call) {
        const auto t0 = Clock::now();
        EXPECT_TRUE(call()) << what;
        const double took = seconds_since(t0);
        std::cerr << what << " with 16 slow bodies being read and 57 refused: " << took * 1000 << " ms\n";
        EXPECT_LT(took, 1.0) << what;
    };
    timed("healthz", [&] {
        auto r = client("").Get("/healthz");
        return r && r->status == 200;
    });
    timed("list jobs", [&] {
        auto r = client(kAlice).Get("/v1/jobs");
        return r && r->status == 200;
    });
    timed("another token's upload", [&] {
        auto r = client(kBob).Post("/v1/scenes", glb("bob"), "model/gltf-binary");
        return r && r->status == 201;
    });

    // The slow tenant's places come back when its requests end.
    slow.clear();
    second.clear();
    int status = 0;
    for (const auto deadline = Clock::now() + 3s; status != 201 && Clock::now() < deadline;) {
        auto r = client(slow_token).Post("/v1/scenes", glb("slow tenant"), "model/gltf-binary");
        status = r ? r->status : 0;
        if (status != 201) std::this_thread::sleep_for(50ms);
    }
    EXPECT_EQ(status, 201);
}

// Issue #33: tenants' slow bodies, each within its own share, together held
// every request thread. All bodies together are at most body_reads (half of
// --http-threads), and bodies and event streams together at most three
// quarters of the threads: beyond, 503 + Retry-After naming body_reads (or
// event_streams) before the body is read, while /healthz answers at once;
// a token with no body being read gets one beyond the total. With 16
// threads: 8 bodies; 4 more streams then; 4 bodies with the 8 streams
// (their cap) open. The per-token and per-address caps are raised
// out of the way: one token stands for many tenants.
TEST_F(HttpTest, SlowBodiesOfAllTenantsTogetherLeaveThreadsForTheApi) {
    start({"--http-threads", "16", "--limit", "body_reads_per_token=64", "--limit", "body_reads_per_address=64",
           "--limit", "request_seconds=20"});
    engine.set("delay", "0.05");
    std::map<std::string, std::string> jobs;  // a long job of each token's own, for its event streams
    for (const std::string& token : {kTokens[0], kTokens[1], kTokens[3], kTokens[4]}) {
        jobs[token] = submit(upload(token, "bodies " + token), 400, 1, token);
        ASSERT_FALSE(jobs[token].empty());
    }
    auto slow_uploads = [&](int n) {  // a thousand bytes announced, ten sent
        std::vector<std::unique_ptr<RawSocket>> sockets;
        for (int i = 0; i < n; ++i) {
            sockets.push_back(std::make_unique<RawSocket>(server->port, "127.0.0.2"));
            sockets.back()->send(request("POST", "/v1/scenes", kTokens[2],
                                         "Content-Type: model/gltf-binary\r\nContent-Length: 1000\r\n") +
                                 "0123456789");
        }
        return sockets;
    };
    auto api_answers_at_once = [&](const std::string& when) {
        const auto t0 = Clock::now();
        auto r = client("").Get("/healthz");
        EXPECT_TRUE(r && r->status == 200) << when;
        EXPECT_LT(seconds_since(t0), 1.0) << "/healthz " << when;
        const auto t1 = Clock::now();
        r = client(kAlice).Get("/v1/jobs");
        EXPECT_TRUE(r && r->status == 200) << when;
        EXPECT_LT(seconds_since(t1), 1.0) << "GET /v1/jobs " << when;
    };
    // Event streams of `token` from `address`: how many were accepted; a
    // refusal names event_streams.
    std::vector<std::unique_ptr<RawSocket>> streams;
    auto open_streams = [&](const std::string& token, const char* address, int n) {
        int accepted = 0;
        for (int i = 0; i < n; ++i) {
            auto s = std::make_unique<RawSocket>(server->port, address);
            s->send(request("GET", "/v1/jobs/" + jobs[token] + "/events", token));
            if (s->status() == 200) {
                ++accepted;
            } else {
                EXPECT_NE(s->read("}").find("\"field\": \"event_streams\""), std::string::npos) << s->received();
            }
            streams.push_back(std::move(s));
        }
        return accepted;
    };

    // The server counts a body until its request's handler returns, a moment
    // after the client has its answer: the jobs' submissions above may still
    // hold one (CI saw 7 of 12 read, 5 refused). None is, before the count.
    auto until_no_body_is_read = [&] {
        for (const auto deadline = Clock::now() + 5s;
             metric("lightfarm_http_body_reads") > 0 && Clock::now() < deadline;)
            std::this_thread::sleep_for(20ms);
        ASSERT_EQ(metric("lightfarm_http_body_reads"), 0);
    };
    until_no_body_is_read();

    // Half the threads for bodies.
    auto bodies = slow_uploads(12);
    EXPECT_EQ(refused_naming(bodies, "body_reads", 1500ms), 12 - 8);
    EXPECT_EQ(metric("lightfarm_http_body_reads"), 8);
    api_answers_at_once("with 8 bodies being read");
    // Another tenant's first body is read beyond the total: others' slow bodies do not refuse its upload.
    auto other = client(kBob).Post("/v1/scenes", glb("not refused"), "model/gltf-binary");
    ASSERT_TRUE(other);
    EXPECT_EQ(other->status, 201) << other->body;
    // Then streams up to three quarters: 4 (per token 2, per address 4).
    EXPECT_EQ(open_streams(kTokens[0], "127.0.0.1", 2) + open_streams(kTokens[1], "127.0.0.1", 2) +
                  open_streams(kTokens[3], "127.0.0.3", 2),
              4);
    api_answers_at_once("with 8 bodies and 4 streams");
    // The bodies gone, streams to their cap (8), and bodies up to three quarters: 4.
    bodies.clear();
    until_no_body_is_read();
    EXPECT_EQ(open_streams(kTokens[3], "127.0.0.3", 2) + open_streams(kTokens[4], "127.0.0.3", 2), 4);
    EXPECT_EQ(metric("lightfarm_event_streams"), 8);
    bodies = slow_uploads(12);
    EXPECT_EQ(refused_naming(bodies, "body_reads", 1500ms), 12 - 4);
    api_answers_at_once("with 8 streams and 4 bodies");
}

// The figures in docs/BENCHMARKS.md, "Fair shares per tenant": 1, 2 or 4
// tenants, each from its own address with its own token, each opening 0 or
// 260 idle sockets, then 64 slow uploads (Content-Length 1000, 10 bytes
// sent; a refused one leaves), while another tenant (127.0.0.1) asks
// /healthz and GET /v1/jobs 200 times each, one connection per request,
// and uploads once. Not run by default (about 20 s):
//   tests/test_server_http --gtest_also_run_disabled_tests --gtest_filter='*FairSharesLoadFigures'
TEST_F(HttpTest, DISABLED_FairSharesLoadFigures) {
    struct Cell {
        int tenants, idle_each;
    };
    const Cell cells[] = {{0, 0}, {1, 0}, {1, 260}, {2, 0}, {2, 260}, {4, 0}, {4, 260}};
    const int kSlowEach = 64, kSamples = 200;
    auto percentile = [](std::vector<double> ms, double p) {
        std::sort(ms.begin(), ms.end());
        return ms[std::min(ms.size() - 1, size_t(p * double(ms.size())))];
    };
    std::ostringstream table;
    table << "| tenants | slow bodies each | idle sockets each | bodies read / refused | idle dropped | /healthz p50 / "
             "p99 / max (ms) | GET /v1/jobs p50 / p99 / max (ms) | another tenant's upload (ms) |\n";
    table << "| --- | --- | --- | --- | --- | --- | --- | --- |\n";
    for (const Cell& cell : cells) {
        start();
        const int slow_each = cell.tenants ? kSlowEach : 0;
        std::vector<std::unique_ptr<RawSocket>> held;
        int refused = 0;
        for (int t = 0; t < cell.tenants; ++t) {
            const std::string address = "127.0.0." + std::to_string(10 + t);
            for (int i = 0; i < cell.idle_each; ++i)
                held.push_back(std::make_unique<RawSocket>(server->port, address.c_str()));
            std::vector<std::unique_ptr<RawSocket>> slow;
            for (int i = 0; i < slow_each; ++i) {
                slow.push_back(std::make_unique<RawSocket>(server->port, address.c_str()));
                slow.back()->send(request("POST", "/v1/scenes", kTokens[size_t(1 + t)],
                                          "Content-Type: model/gltf-binary\r\nContent-Length: 1000\r\n") +
                                  "0123456789");
            }
            // A refused client reads its 503 and leaves; the others keep sending slowly.
            const auto deadline = Clock::now() + 1s;
            for (auto& s : slow) {
                const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
                s->read("\n}\n", std::max<std::chrono::milliseconds>(left, 5ms));
                if (s->received().empty()) held.push_back(std::move(s));
                else ++refused;
            }
        }
        auto sample = [&](const std::string& token, const std::string& path) {
            std::vector<double> ms;
            for (int i = 0; i < kSamples; ++i) {
                const auto t0 = Clock::now();
                auto r = client(token).Get(path);
                ms.push_back(r && r->status == 200 ? seconds_since(t0) * 1000 : 1e9);
            }
            return ms;
        };
        const std::vector<double> health = sample("", "/healthz"), jobs = sample(kAlice, "/v1/jobs");
        const double reading = metric("lightfarm_http_body_reads"),
                     dropped = metric("lightfarm_http_idle_dropped_total");
        const auto t0 = Clock::now();  // new bytes each time: an upload stored before answers at once
        auto up = client(kAlice).Post("/v1/scenes", glb("other tenant, cell " + std::to_string(&cell - cells)),
                                      "model/gltf-binary");
        const double upload_ms = up && up->status == 201 ? seconds_since(t0) * 1000 : -1;
        char row[512];
        std::snprintf(row, sizeof row,
                      "| %d | %d | %d | %.0f / %d | %.0f | %.2f / %.2f / %.2f | %.2f / %.2f / %.2f | %.1f |\n",
                      cell.tenants, slow_each, cell.idle_each, reading, refused, dropped, percentile(health, 0.5),
                      percentile(health, 0.99), percentile(health, 1.0), percentile(jobs, 0.5), percentile(jobs, 0.99),
                      percentile(jobs, 1.0), upload_ms);
        table << row;
        EXPECT_LT(percentile(health, 1.0), 1000) << row;
        EXPECT_LT(percentile(jobs, 1.0), 1000) << row;
        EXPECT_GT(upload_ms, 0) << row << (up ? up->body : "no answer");
        held.clear();
    }
    std::cout << table.str();
}

// Bodies and headers are checked before they are read: the server's peak
// memory stays flat under an unauthenticated 256 MiB body, a chunked body, a
// huge request line and huge headers.
TEST_F(HttpTest, OversizedRequestsAreRefusedBeforeMemoryGrows) {
    start({"--limit", "upload_bytes=1048576"});
    const pid_t pid = server->pid();
    ASSERT_GT(pid, 0);
    const long hwm_before = proc_status_kb(pid, "VmHWM");
    ASSERT_GT(hwm_before, 0);
    const std::string mib(1 << 20, 'x');

    {  // unauthenticated, 256 MiB announced: 401 before the body; at most 16 MiB sent
        RawSocket s(server->port);
        s.send(request("POST", "/v1/scenes", "", "Content-Type: model/gltf-binary\r\nContent-Length: 268435456\r\n"));
        size_t sent = 0;
        for (int i = 0; i < 16 && sent == size_t(i) << 20; ++i) sent += s.send(mib);
        EXPECT_EQ(s.status(), 401) << s.received();
    }
    {  // unauthenticated chunked: 401 too
        RawSocket s(server->port);
        s.send(request("POST", "/v1/scenes", "", "Content-Type: model/gltf-binary\r\nTransfer-Encoding: chunked\r\n"));
        for (int i = 0; i < 16; ++i)
            if (s.send("100000\r\n" + mib + "\r\n") == 0) break;
        EXPECT_EQ(s.status(), 401) << s.received();
    }
    {  // authenticated chunked: 411, never stored past the limit
        RawSocket s(server->port);
        s.send(
            request("POST", "/v1/scenes", kAlice, "Content-Type: model/gltf-binary\r\nTransfer-Encoding: chunked\r\n"));
        for (int i = 0; i < 3; ++i)
            if (s.send("100000\r\n" + mib + "\r\n") == 0) break;
        EXPECT_EQ(s.status(), 411) << s.received();
    }
    {  // authenticated, over upload_bytes by its Content-Length: 413 before the body
        RawSocket s(server->port);
        s.send(request("POST", "/v1/scenes", kAlice, "Content-Type: model/gltf-binary\r\nContent-Length: 3145728\r\n"));
        EXPECT_EQ(s.status(), 413) << s.received();
        s.peer_closed(2s);  // the whole answer, body included
        EXPECT_NE(s.received().find("upload_bytes"), std::string::npos);
    }
    {  // Expect: 100-continue without a token: the 401 comes instead of the 100
        RawSocket s(server->port);
        s.send(request("POST", "/v1/scenes", "", "Content-Length: 1000\r\nExpect: 100-continue\r\n"));
        EXPECT_EQ(s.status(), 401) << s.received();
    }
    {  // a request line of up to 64 MiB: 414 after 8 KiB, and the sender is cut off
        RawSocket s(server->port);
        s.send("GET /");
        size_t sent = 0;
        for (int i = 0; i < 64; ++i) {
            const size_t n = s.send(std::string(1 << 20, 'a'));
            sent += n;
            if (n < (1u << 20)) break;
        }
        EXPECT_EQ(s.status(), 414) << s.received().substr(0, 200);
        EXPECT_LT(sent, size_t(48) << 20);
    }
    {  // headers past header_bytes (64 KiB): 431
        RawSocket s(server->port);
        std::string headers;
        for (int i = 0; i < 200; ++i)
            headers += "X-Filler-" + std::to_string(i) + ": " + std::string(1000, 'h') + "\r\n";
        s.send(request("GET", "/healthz", "", headers));
        EXPECT_EQ(s.status(), 431) << s.received().substr(0, 200);
    }
    // An upload within the limit still works, and nothing over it was stored.
    auto r = client().Post("/v1/scenes", glb("small"), "model/gltf-binary");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 201);

    const long hwm_after = proc_status_kb(pid, "VmHWM");
    std::cerr << "lightfarmd VmHWM: " << hwm_before << " kB before, " << hwm_after << " kB after\n";
    EXPECT_LT(hwm_after - hwm_before, 16 * 1024) << "peak memory grew by " << (hwm_after - hwm_before) << " kB";
}

// A client that writes its whole body before it reads its answer (httplib's
// Client, Python's requests) gets every early refusal, not a reset: a job
// spec one byte over spec_bytes, twice it, almost four times it; an upload
// over upload_bytes; a body without a token. Each is written in full first,
// then read. (A 2 MiB spec's 413 was lost to a reset once the server had
// discarded 1 MiB, and the SIGPIPE ended the test binary that sent it.)
TEST_F(HttpTest, ABodyWrittenInFullBeforeReadingStillGetsItsEarlyRefusal) {
    start({"--limit", "upload_bytes=1048576", "--limit", "spec_bytes=1048576"});
    struct Case {
        const char* path;
        std::string token;
        size_t bytes;
        int status;
        const char* field;
    };
    const size_t mib = 1 << 20;
    const std::vector<Case> cases = {
        {"/v1/jobs", kAlice, mib + 1, 413, "spec_bytes"},
        {"/v1/jobs", kAlice, 2 * mib, 413, "spec_bytes"},
        {"/v1/jobs", kAlice, 4 * mib - 64 * 1024, 413, "spec_bytes"},
        {"/v1/scenes", kAlice, 3 * mib, 413, "upload_bytes"},
        {"/v1/jobs", "", 2 * mib, 401, nullptr},
    };
    for (const Case& c : cases) {
        SCOPED_TRACE(std::string(c.path) + " with " + std::to_string(c.bytes) + " bytes");
        RawSocket s(server->port);
        ASSERT_TRUE(s.connected());
        const std::string head =
            request("POST", c.path, c.token,
                    std::string("Content-Type: ") +
                        (std::string(c.path) == "/v1/scenes" ? "model/gltf-binary" : "application/json") +
                        "\r\nContent-Length: " + std::to_string(c.bytes) + "\r\n");
        const std::string body(c.bytes, ' ');
        EXPECT_EQ(s.send(head + body), head.size() + body.size()) << "the server stopped reading the body";
        EXPECT_EQ(s.status(), c.status) << s.received().substr(0, 300);
        s.peer_closed(2s);  // the whole answer, body included
        if (c.field) {
            EXPECT_NE(s.received().find(std::string("\"") + c.field + "\""), std::string::npos);
        }
    }
    // The same through an HTTP client library that writes, then reads.
    auto r = client().Post("/v1/jobs", std::string(2 * mib, ' '), "application/json");
    ASSERT_TRUE(r) << httplib::to_string(r.error());
    EXPECT_EQ(r->status, 413) << r->body;
}

// The gate reads a request's headers exactly as cpp-httplib does (issue
// #55: a bare-LF "Content-Length: 0" line before the real one made the
// gate count no body while httplib read one; a percent-escaped token was
// another budget's key while the service decoded it to the same token).
// The oracle is httplib itself: a plain httplib::Server in this process
// echoes what it read for three names, and the gate's header_value reads
// the same bytes. Drawn heads (seed printed): lines ending in CRLF or a
// bare LF, bare-LF blank lines, names in any case, repeated names, values
// padded with spaces and tabs, empty, or holding percent-escapes.
TEST(HttpGate, ReadsHeadersExactlyAsHttplibDoes) {
    httplib::Server echo;
    const std::vector<std::string> names = {"Authorization", "X-Length", "X-Probe"};
    echo.Get("/", [&](const httplib::Request& req, httplib::Response& res) {
        nlohmann::json read;
        for (const std::string& name : names) read[name] = req.get_header_value(name);
        res.set_content(read.dump(), "application/json");
    });
    const int port = echo.bind_to_any_port("127.0.0.1");
    std::thread serving([&] { echo.listen_after_bind(); });
    std::mt19937 rng(5505);
    std::printf("  seed 5505\n");
    std::uniform_int_distribution<int> pick(0, 1 << 20);
    const std::vector<std::string> values = {"0", "5", "Bearer abc",    "Bearer a%62c", "%30",   " \t7\t ",
                                             "",  " ", "Bearer %41%42", "a%2",          "x%zzy", "Bearer"};
    int compared = 0;
    for (int draw = 0; draw < 200; ++draw) {
        std::string head = "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n";
        const int lines = 1 + pick(rng) % 6;
        for (int l = 0; l < lines; ++l) {
            if (pick(rng) % 8 == 0) {
                head += "\n";  // a bare-LF blank line
                continue;
            }
            std::string name = names[size_t(pick(rng)) % names.size()];
            for (char& c : name)
                if (pick(rng) % 3 == 0) c = char(pick(rng) % 2 ? std::tolower(c) : std::toupper(c));
            head += name + ":" + values[size_t(pick(rng)) % values.size()] + (pick(rng) % 3 == 0 ? "\n" : "\r\n");
        }
        head += "\r\n";
        RawSocket s(port);
        ASSERT_TRUE(s.connected());
        s.send(head);
        const std::string answer = s.read("");
        const size_t body = answer.find("\r\n\r\n");
        ASSERT_NE(body, std::string::npos) << head;
        const nlohmann::json read = nlohmann::json::parse(answer.substr(body + 4), nullptr, false);
        ASSERT_TRUE(read.is_object()) << answer;
        for (const std::string& name : names) {
            EXPECT_EQ(lf::server::gate::header_value(head, name), read[name].get<std::string>()) << name << " in\n"
                                                                                                 << head;
            ++compared;
        }
    }
    echo.stop();
    serving.join();
    EXPECT_EQ(compared, 600);
    // And the budget's key: the token the service authenticates.
    EXPECT_EQ(lf::server::gate::bearer_token("GET / HTTP/1.1\r\nAuthorization: Bearer a%62c\r\n\r\n"), "abc");
    EXPECT_TRUE(lf::server::gate::has_body("POST / HTTP/1.1\r\nContent-Length: 0\nContent-Length: 5\r\n\r\n"));
    EXPECT_FALSE(lf::server::gate::has_body("POST / HTTP/1.1\r\nContent-Length: 5\nContent-Length: 0\r\n\r\n"));
}

// SIGTERM with a slow upload in flight (issue #33): the upload may take up
// to request_seconds (300 s by default), but a stop gives requests in flight
// drain_seconds, then closes their connections; it waited 32 s for one.
// The upload trickles 1 KiB a second towards 64 MiB, so without the bound
// the stop would wait out request_seconds (60 s here); with drain_seconds 1
// lightfarmd is gone within a few seconds, and nothing of the upload is stored.
TEST_F(HttpTest, AStopWaitsForRequestsInFlightNoLongerThanTheDrain) {
    const auto slow = upload_in_flight(1s);
    const auto stopping = Clock::now();
    server->stop();
    const double took = seconds_since(stopping);
    slow->stop();
    EXPECT_LT(took, 4.5) << "the stop waited for the upload";
    const std::string log = server->log();
    EXPECT_NE(log.find("lightfarmd: stopped\n"), std::string::npos) << log;
    EXPECT_TRUE(fs::is_empty(tmp.path / "data" / "scenes")) << "nothing of the cut upload is stored";
    server->start();  // and it starts again
    EXPECT_EQ(client().Get("/healthz")->status, 200);
}

// A stop asked again and again (issue #55: each stop pushed the drain's
// deadline on, and an upload in flight held SIGTERM for 299 s): SIGTERM
// every 0.2 s while an upload trickles in, until lightfarmd is gone. The
// first stop's deadline holds, so it is gone within drain_seconds (1 s)
// and the few seconds a stop takes, not after request_seconds (60 s), and
// it stopped cleanly, not by the harness's SIGKILL.
TEST_F(HttpTest, AStopAskedAgainKeepsTheFirstStopsDeadline) {
    const auto slow = upload_in_flight(200ms);
    const auto stopping = Clock::now();
    bool gone = false;
    for (int i = 0; i < 100 && !gone; ++i) gone = server->signal_and_wait(SIGTERM, 0.2);
    const double took = seconds_since(stopping);
    slow->stop();
    ASSERT_TRUE(gone) << "still running after 20 s of stops";
    EXPECT_LT(took, 4.5) << "each stop pushed the drain on";
    const std::string log = server->log();
    EXPECT_NE(log.find("lightfarmd: stopped\n"), std::string::npos) << log;
}

// `curl -X POST -H "$T" $S/v1/jobs/JOB/cancel`: no body, no Content-Length.
TEST_F(HttpTest, CancelWithoutABody) {
    start();
    engine.set("delay", "0.2");
    const std::string job = submit(upload(kAlice, "cancel"), 100, 1);
    RawSocket s(server->port);
    const auto t0 = Clock::now();
    s.send(request("POST", "/v1/jobs/" + job + "/cancel", kAlice));
    EXPECT_EQ(s.status(), 200) << s.received();
    EXPECT_LT(seconds_since(t0), 1.0);
    s.read("\n}\n", 1s);
    EXPECT_NE(s.received().find("\"cancelled\""), std::string::npos) << s.received();
    // The connection stays usable: the next request on it is answered.
    s.send(request("GET", "/healthz", ""));
    s.read("\"ok\"", 2s);
    EXPECT_NE(s.received().find("\"ok\""), std::string::npos);
    // A POST /v1/jobs without a body is a prompt 400, not a 5 s wait.
    RawSocket j(server->port);
    const auto t1 = Clock::now();
    j.send(request("POST", "/v1/jobs", kAlice));
    EXPECT_EQ(j.status(), 400) << j.received();
    EXPECT_LT(seconds_since(t1), 1.0);
}

// Names with NUL, control characters or invalid UTF-8 are 400, never
// truncated or guessed; no answer carries an exception header or a path.
TEST_F(HttpTest, NamesAreExactlyWhatTheySay) {
    start();
    const std::string job = submit(upload(kAlice, "names"), 2, 1);
    auto c = client();
    const json done = wait_for_job(c, job, is_finished);
    ASSERT_EQ(done.value("state", ""), "succeeded");

    auto status_of = [&](const std::string& path) {
        RawSocket s(server->port);
        s.send(request("GET", path, kAlice));
        const int status = s.status();
        s.read("\n}\n", 1s);
        EXPECT_EQ(s.received().find("EXCEPTION_WHAT"), std::string::npos) << path;
        EXPECT_EQ(s.received().find(tmp.path.string()), std::string::npos) << path;
        EXPECT_EQ(s.received().find("9223372036854775807"), std::string::npos) << path;
        return status;
    };
    const std::string base = "/v1/jobs/" + job;
    EXPECT_EQ(status_of(base + "/artifacts/%00"), 400);
    EXPECT_EQ(status_of(base + "/artifacts/manifest.json%00.png"), 400);
    EXPECT_EQ(status_of(base + "/artifacts/manifest%0d%0a.json"), 400);
    EXPECT_EQ(status_of(base + "/artifacts/%C0%AF"), 400);  // an overlong '/'
    EXPECT_EQ(status_of("/v1/jobs/%FF"), 400);
    EXPECT_EQ(status_of("/v1/jobs/%01" + job), 400);
    EXPECT_EQ(status_of("/v1/scenes/%ED%A0%80"), 400);  // a surrogate
    EXPECT_EQ(status_of("/?token=a%00b"), 400);
    // What is well formed is answered as before.
    EXPECT_EQ(status_of(base + "/artifacts/manifest.json"), 200);
    EXPECT_EQ(status_of(base + "/artifacts/nothing.png"), 404);
    EXPECT_EQ(status_of(base + "/artifacts/%C3%A9t%C3%A9.exr"), 404);  // valid UTF-8, no such file
    EXPECT_EQ(status_of("/v1/jobs/0123"), 404);

    // An upload as curl sends it without -H 'Content-Type: …' is a 415 that
    // says what to send, not a 413.
    auto r = c.Post("/v1/scenes", std::string(187 * 1024, 'g'), "application/x-www-form-urlencoded");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 415);
    EXPECT_NE(r->body.find("model/gltf-binary"), std::string::npos);
    // A job spec sent that way is still read as the JSON it is.
    r = c.Post("/v1/jobs", json{{"scene", "nope"}, {"outputs", {{"lightmap", json::object()}}}}.dump(),
               "application/x-www-form-urlencoded");
    ASSERT_TRUE(r);
    EXPECT_EQ(r->status, 404) << r->body;  // the scene does not exist: the spec was read
}

// The cache does not cross tenants (issue #55): another token's job of
// the same bytes and settings is baked, not answered from the first
// token's files (a hit, in milliseconds where a bake takes seconds, told
// that someone had baked them so), and names nothing of it; the same
// token's second job is a hit that names its earlier job.
TEST_F(HttpTest, TheCacheServesATokenOnlyItsOwnBakes) {
    start();
    const std::string scene = upload(kAlice, "shared-bytes");
    const std::string first = submit(scene, 2, 7);
    auto c = client();
    ASSERT_EQ(wait_for_job(c, first, is_finished).value("state", ""), "succeeded");

    auto done_event = [&](const std::string& token, const std::string& id) {
        for (const auto& e : read_events(server->host, server->port, token, id, -1, 0, 20s))
            if (e.type == "done") return e.data;
        return json();
    };
    ASSERT_EQ(upload(kBob, "shared-bytes"), scene);  // the same bytes: the same scene
    const int runs = engine.runs();
    const std::string bobs = submit(scene, 2, 7, kBob);
    const json bob_done = done_event(kBob, bobs);
    ASSERT_TRUE(bob_done.is_object());
    EXPECT_FALSE(bob_done.value("cached", false)) << bob_done.dump();
    EXPECT_EQ(engine.runs(), runs + 1) << "Bob's job was baked";
    EXPECT_EQ(bob_done.dump().find(first), std::string::npos) << bob_done.dump();
    auto r = client(kBob).Get("/v1/jobs/" + bobs);
    ASSERT_TRUE(r);
    EXPECT_EQ(r->body.find(first), std::string::npos);

    const std::string again = submit(scene, 2, 7, kAlice);
    const json alice_again = done_event(kAlice, again);
    EXPECT_EQ(alice_again.value("cached", false), true) << alice_again.dump();
    EXPECT_EQ(alice_again.value("cached_from", ""), first);
}

}  // namespace
}  // namespace lf::test
