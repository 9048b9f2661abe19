// lightfarmd under load on loopback: 50 concurrent small jobs from 10 clients
// (each with its own token) while 200 readers follow them (100 poll job status,
// 100 follow event streams). Every job must finish exactly once, none lost or
// duplicated; the test prints the status latency (p50/p99) and jobs/s.
//
// By default the engine is the fake one (tests/server_harness.cpp), so the
// figures are the service's own cost, not the bake's. For the figures with
// the real engine:
//   LIGHTFARM_LOAD_ENGINE=real build/tests/test_server_load
// (or =/path/to/lightfarm). LIGHTFARM_LOAD_WORKERS=N overrides the number of
// workers (fake: 4, real: 1), LIGHTFARM_LOAD_REPORT=FILE appends the figures
// as a Markdown table row to FILE.
#include "server_harness.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <fstream>
#include <map>
#include <mutex>
#include <numeric>
#include <set>
#include <sstream>
#include <thread>

namespace lf::test {
namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;

constexpr int kClients = 10;
constexpr int kJobsPerClient = 5;
constexpr int kJobs = kClients * kJobsPerClient;
constexpr int kStatusReaders = 100;
constexpr int kEventReaders = 100;
// A status reader's pause between two requests: 100 readers offer about
// 100 / 50 ms = 2000 requests/s.
constexpr auto kPollInterval = std::chrono::milliseconds(50);

std::string token_of(int client) { return "load-client-" + std::to_string(client) + "-token"; }

std::string env(const char* name) {
    const char* v = std::getenv(name);
    return v ? v : "";
}

double ms(Clock::duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

double percentile(std::vector<double> v, double p) {
    if (v.empty()) return 0;
    std::sort(v.begin(), v.end());
    const size_t i = std::min(v.size() - 1, size_t(p * double(v.size())));
    return v[i];
}

// What a job is once submitted: its id and its owner.
struct Submitted {
    std::string id;
    int client;
};

TEST(Load, FiftyJobsFromTenClientsWithTwoHundredReadersEachFinishExactlyOnce) {
    TempDir tmp;
    // The engine: the fake one unless LIGHTFARM_LOAD_ENGINE names a real one.
    std::string engine_choice = env("LIGHTFARM_LOAD_ENGINE");
    fs::path engine_path;
    std::unique_ptr<FakeEngine> fake;
    bool real = !engine_choice.empty();
    if (real) {
#ifdef LIGHTFARM_ENGINE
        engine_path =
            engine_choice == "real" || engine_choice == "1" ? fs::path(LIGHTFARM_ENGINE) : fs::path(engine_choice);
#else
        engine_path = engine_choice;
#endif
        ASSERT_TRUE(fs::exists(engine_path)) << "no engine at " << engine_path;
    } else {
        fake = std::make_unique<FakeEngine>(tmp.path / "engine");
        engine_path = fake->script;
    }
    const int workers =
        env("LIGHTFARM_LOAD_WORKERS").empty() ? (real ? 1 : 4) : std::stoi(env("LIGHTFARM_LOAD_WORKERS"));
    const auto job_deadline = real ? std::chrono::seconds(600) : std::chrono::seconds(45);

    std::string tokens;
    for (int c = 0; c < kClients; ++c) tokens += token_of(c) + "\n";
    write_text(tmp.path / "tokens", tokens);
    // Every reader and submitter holds a request thread at a time. All of
    // them come from 127.0.0.1, as from behind a proxy: one address may hold
    // every connection (the default is 64) and every event stream (the
    // default is half of them).
    Lightfarmd server(tmp.path / "data", tmp.path / "tokens", engine_path,
                      {"--workers", std::to_string(workers), "--http-threads", "256", "--stall-timeout", "120",
                       "--limit", "connections_per_address=512", "--limit", "event_streams_per_address=128"});
    server.start();

    // The scene each client uploads: the Cornell box for the real engine
    // (equal bytes, so one stored scene owned by every token), a distinct
    // tiny .glb per client for the fake one.
    const char* scenes_env = std::getenv("LIGHTFARM_SCENES");
    const fs::path cornell = fs::path(scenes_env && *scenes_env ? scenes_env : LIGHTFARM_EXAMPLES) / "cornell_box.gltf";
    const std::string real_scene = real ? read_text(cornell) : "";

    std::mutex mutex;
    std::vector<Submitted> submitted;  // in submission order
    std::vector<double> submit_ms;
    std::vector<std::string> errors;  // anything that went wrong, for the report
    std::atomic<bool> all_done{false};
    const auto give_up = Clock::now() + job_deadline;
    auto note_error = [&](const std::string& e) {
        std::lock_guard lock(mutex);
        if (errors.size() < 50) errors.push_back(e);
    };
    // A reader waits (bounded) until job `n` has been submitted.
    auto nth_job = [&](size_t n) -> std::optional<Submitted> {
        while (Clock::now() < give_up && !all_done) {
            {
                std::lock_guard lock(mutex);
                if (submitted.size() > n) return submitted[n];
            }
            std::this_thread::sleep_for(std::chrono::milliseconds(5));
        }
        return std::nullopt;
    };

    const auto t_start = Clock::now();
    std::vector<std::thread> clients;
    for (int c = 0; c < kClients; ++c) {
        clients.emplace_back([&, c] {
            auto http = server.client(token_of(c));
            http.set_read_timeout(60);
            const std::string body =
                real ? real_scene : std::string("glTF\x02\x00\x00\x00", 8) + " load scene " + std::to_string(c);
            auto up = http.Post("/v1/scenes", body, real ? "model/gltf+json" : "model/gltf-binary");
            if (!up || (up->status != 201 && up->status != 200)) {
                note_error("client " + std::to_string(c) + ": upload: " + (up ? up->body : "no answer"));
                return;
            }
            const std::string scene = json::parse(up->body)["id"];
            for (int j = 0; j < kJobsPerClient; ++j) {
                // Distinct seeds: distinct bakes, none served from the cache.
                const json lightmap = real ? json{{"passes", 8}} : json{{"passes", 4}};
                json spec = {{"scene", scene}, {"outputs", {{"lightmap", lightmap}}}, {"seed", 1000 * c + j}};
                if (real) spec["atlas"] = {{"res", 32}};
                const auto t0 = Clock::now();
                auto r = http.Post("/v1/jobs", spec.dump(), "application/json");
                const double took = ms(Clock::now() - t0);
                if (!r || r->status != 201) {
                    note_error("client " + std::to_string(c) + ": submit: " + (r ? r->body : "no answer"));
                    continue;
                }
                std::lock_guard lock(mutex);
                submitted.push_back({json::parse(r->body)["id"], c});
                submit_ms.push_back(took);
            }
        });
    }

    // Status readers: reader r polls job r % 50 until every job is finished.
    std::vector<std::vector<double>> status_ms(kStatusReaders);
    std::atomic<int> status_errors{0};
    std::vector<std::thread> readers;
    for (int r = 0; r < kStatusReaders; ++r) {
        readers.emplace_back([&, r] {
            const std::optional<Submitted> job = nth_job(size_t(r % kJobs));
            if (!job) return;
            auto http = server.client(token_of(job->client));
            while (!all_done && Clock::now() < give_up) {
                const auto t0 = Clock::now();
                auto res = http.Get("/v1/jobs/" + job->id);
                const double took = ms(Clock::now() - t0);
                if (!res || res->status != 200) {
                    ++status_errors;
                    note_error("status " + job->id + ": " +
                               (res ? std::to_string(res->status) : httplib::to_string(res.error())));
                } else {
                    status_ms[size_t(r)].push_back(took);
                }
                std::this_thread::sleep_for(kPollInterval);
            }
        });
    }

    // Event readers: reader r follows job r % 50 from its first event to its
    // final one; ids must run 1, 2, 3 ... and the final event come once, last.
    std::atomic<int> streams_whole{0};
    std::atomic<int64_t> events_seen{0};
    for (int r = 0; r < kEventReaders; ++r) {
        readers.emplace_back([&, r] {
            const std::optional<Submitted> job = nth_job(size_t(r % kJobs));
            if (!job) return;
            const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(give_up - Clock::now());
            const auto events = read_events(server.host, server.port, token_of(job->client), job->id, -1, 0, left);
            events_seen += int64_t(events.size());
            int finals = 0;
            bool in_order = true;
            for (size_t i = 0; i < events.size(); ++i) {
                in_order = in_order && events[i].id == int64_t(i + 1);
                finals += protocol::is_final_event(events[i].type);
            }
            if (!events.empty() && in_order && finals == 1 && events.back().type == "done") ++streams_whole;
            else
                note_error("events of " + job->id + ": " + std::to_string(events.size()) + " events, " +
                           std::to_string(finals) + " final, " + (in_order ? "in order" : "ids out of order"));
        });
    }

    for (std::thread& t : clients) t.join();
    const auto t_submitted = Clock::now();
    if (submitted.size() != size_t(kJobs)) {
        all_done = true;
        for (std::thread& t : readers) t.join();
        FAIL() << submitted.size() << " of " << kJobs << " jobs submitted: " << (errors.empty() ? "" : errors.front());
    }

    // Wait (bounded) until every token's list shows its jobs finished.
    std::map<std::string, json> final_status;
    while (Clock::now() < give_up) {
        final_status.clear();
        for (int c = 0; c < kClients; ++c) {
            auto http = server.client(token_of(c));
            auto r = http.Get("/v1/jobs");
            if (!r || r->status != 200) continue;
            const json list = json::parse(r->body);  // (not a temporary: the loop would iterate a dangling reference)
            for (const json& j : list["jobs"]) {
                if (is_finished(j)) final_status[j["id"]] = j;
            }
        }
        if (final_status.size() >= size_t(kJobs)) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    const auto t_finished = Clock::now();
    all_done = true;
    for (std::thread& t : readers) t.join();

    // --- exactly once: every job listed once, by its own token only, succeeded
    // after one attempt, with one "started" and one "done" event.
    std::set<std::string> ids;
    for (const Submitted& s : submitted) ids.insert(s.id);
    EXPECT_EQ(ids.size(), size_t(kJobs)) << "duplicate job ids";
    double first_created = 1e300, last_finished = 0;
    for (int c = 0; c < kClients; ++c) {
        auto http = server.client(token_of(c));
        auto r = http.Get("/v1/jobs");
        ASSERT_TRUE(r && r->status == 200);
        std::multiset<std::string> listed, expected;
        const json list = json::parse(r->body);
        for (const json& j : list["jobs"]) {
            listed.insert(j["id"].get<std::string>());
            EXPECT_EQ(j["state"], "succeeded") << j.dump();
            EXPECT_EQ(j["attempts"], 1) << j.dump();
            EXPECT_EQ(j["cached"], false) << j.dump();
            first_created = std::min(first_created, j["created_at"].get<double>());
            last_finished = std::max(last_finished, j["finished_at"].get<double>());
        }
        for (const Submitted& s : submitted)
            if (s.client == c) expected.insert(s.id);
        EXPECT_EQ(listed, expected) << "client " << c << "'s job list";
    }
    for (const Submitted& s : submitted) {
        const auto events = read_events(server.host, server.port, token_of(s.client), s.id);
        std::map<std::string, int> count;
        for (const auto& e : events) ++count[e.type];
        EXPECT_EQ(count["started"], 1) << s.id;
        EXPECT_EQ(count["done"], 1) << s.id;
        EXPECT_EQ(count["failed"] + count["cancelled"] + count["retrying"], 0) << s.id;
        ASSERT_FALSE(events.empty());
        EXPECT_EQ(events.back().type, "done") << s.id;
    }
    auto metrics = server.client(token_of(0)).Get("/metrics");
    ASSERT_TRUE(metrics && metrics->status == 200);
    EXPECT_NE(metrics->body.find("lightfarm_worker_starts_total " + std::to_string(kJobs) + "\n"), std::string::npos)
        << "one worker run per job";
    EXPECT_NE(metrics->body.find("lightfarm_worker_failures_total 0\n"), std::string::npos);
    EXPECT_NE(metrics->body.find("lightfarm_jobs{state=\"succeeded\"} " + std::to_string(kJobs) + "\n"),
              std::string::npos);
    EXPECT_EQ(server.client(token_of(0)).Get("/healthz")->status, 200);

    EXPECT_EQ(streams_whole.load(), kEventReaders) << (errors.empty() ? "" : errors.front());
    EXPECT_EQ(status_errors.load(), 0) << (errors.empty() ? "" : errors.front());

    // --- the figures
    std::vector<double> all_status;
    for (const auto& v : status_ms) all_status.insert(all_status.end(), v.begin(), v.end());
    const double wall = last_finished - first_created;  // server clock: first job created .. last job finished
    std::ostringstream report;
    report.setf(std::ios::fixed);
    report.precision(1);
    report << "load: " << kJobs << " jobs from " << kClients << " clients, " << kStatusReaders << " status + "
           << kEventReaders << " event readers, " << workers << " worker(s), engine "
           << (real ? engine_path.filename().string() + " (real)" : std::string("fake")) << "\n"
           << "  jobs: " << final_status.size() << " finished in " << wall
           << " s (first created .. last finished) = " << double(kJobs) / wall << " jobs/s; submitting took "
           << ms(t_submitted - t_start) << " ms, waiting " << ms(t_finished - t_submitted) << " ms\n";
    report.precision(2);
    report << "  status (GET /v1/jobs/{id}): " << all_status.size() << " requests, p50 " << percentile(all_status, 0.5)
           << " ms, p99 " << percentile(all_status, 0.99) << " ms, max " << percentile(all_status, 1.0) << " ms, "
           << status_errors.load() << " errors\n"
           << "  submit (POST /v1/jobs): p50 " << percentile(submit_ms, 0.5) << " ms, p99 "
           << percentile(submit_ms, 0.99) << " ms\n"
           << "  events: " << streams_whole.load() << "/" << kEventReaders << " streams whole, " << events_seen.load()
           << " events delivered\n";
    std::cout << report.str();
    for (const std::string& e : errors) std::cout << "  error: " << e << "\n";
    RecordProperty("status_p50_ms", std::to_string(percentile(all_status, 0.5)));
    RecordProperty("status_p99_ms", std::to_string(percentile(all_status, 0.99)));
    RecordProperty("jobs_per_second", std::to_string(double(kJobs) / wall));

    if (const std::string file = env("LIGHTFARM_LOAD_REPORT"); !file.empty()) {
        std::ofstream out(file, std::ios::app);
        out.setf(std::ios::fixed);
        out.precision(2);
        out << "| " << (real ? "real (llvmpipe or GPU)" : "fake") << " | " << workers << " | " << kJobs << " | " << wall
            << " s | " << double(kJobs) / wall << " | " << all_status.size() << " | " << percentile(all_status, 0.5)
            << " ms | " << percentile(all_status, 0.99) << " ms | " << percentile(all_status, 1.0) << " ms | "
            << streams_whole.load() << "/" << kEventReaders << " |\n";
    }
    if (HasFailure()) std::cerr << "---- lightfarmd log ----\n" << server.log();
}

}  // namespace
}  // namespace lf::test
