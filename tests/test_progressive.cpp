// The progressive loop's snapshot schedule and the writer thread that takes
// snapshots off the passes (issue #12): pure logic, no GL.
#include "bake/event_heartbeat.h"
#include "bake/method_state.h"
#include "bake/output_methods.h"
#include "bake/preparation_estimate.h"
#include "bake/progressive.h"
#include "bake/snapshot_writer.h"

#include "bake/bake_job.h"
#include "outputs.h"
#include <gtest/gtest.h>
#include <unistd.h>
#include <fstream>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>
#include <future>
#include <stdexcept>
#include <thread>

namespace lf {
namespace {

// Passes 1..n at `pass_seconds` each; the passes at which a snapshot is taken
// when each costs `cost` seconds and the writer is always idle.
std::vector<int> taken(SnapshotSchedule& schedule, int n, double pass_seconds, double cost) {
    std::vector<int> passes;
    for (int pass = 1; pass <= n; ++pass)
        if (schedule.due(pass, pass * pass_seconds, true)) {
            passes.push_back(pass);
            schedule.record_cost(cost);
        }
    return passes;
}

// Events with no long silence (issue #54): a stage of preparation or a
// pass that runs long has its last prepare or progress event said again,
// its seconds moved on by the time since (and a prepare event's time left
// moved down); start, snapshot and done are said once; nothing after
// stop(). Waits for what it expects (bounded at 30 s) rather than timing
// it, so a busy machine only makes it slower.
TEST(EventHeartbeat, SaysTheLastPrepareOrProgressAgainAndFactsOnce) {
    std::mutex mutex;
    std::condition_variable arrived;
    std::vector<protocol::WorkerEvent> events;
    EventHeartbeat heartbeat([&](const protocol::WorkerEvent& e) {
        const std::lock_guard<std::mutex> lock(mutex);
        events.push_back(e);
        arrived.notify_all();
    });
    const BakeEventSink emit = heartbeat.sink();
    const auto wait_for_events = [&](size_t n) {
        std::unique_lock<std::mutex> lock(mutex);
        return arrived.wait_for(lock, std::chrono::seconds(30), [&] { return events.size() >= n; });
    };

    emit(protocol::PrepareEvent{"methods", 3.0, 20.0});
    ASSERT_TRUE(wait_for_events(2)) << "a long stage is said again";
    {
        const std::lock_guard<std::mutex> lock(mutex);
        const auto& again = std::get<protocol::PrepareEvent>(events[1]);
        EXPECT_EQ(again.stage, "methods");
        EXPECT_TRUE(again.again) << "marked as said again";
        EXPECT_FALSE(std::get<protocol::PrepareEvent>(events[0]).again);
        EXPECT_GE(again.seconds, 3.0 + EventHeartbeat::kPeriodSeconds);
        ASSERT_TRUE(again.eta_seconds.has_value());
        EXPECT_NEAR(*again.eta_seconds + again.seconds, 23.0, 1e-6) << "time left moves down as seconds move on";
    }

    protocol::StartEvent start;
    start.renderer = "test";
    emit(start);
    protocol::Progress at;
    at.pass = 16;
    at.rays = 1000;
    at.seconds = 5.0;
    emit(protocol::ProgressEvent{"lightmap", at});
    emit(protocol::SnapshotEvent{"lightmap", "lightmap.pass-0016.exr", 16});
    size_t said = 0;
    {
        const std::lock_guard<std::mutex> lock(mutex);
        said = events.size();
    }
    ASSERT_TRUE(wait_for_events(said + 1)) << "a long pass, or the final writes, say the last progress again";
    {
        const std::lock_guard<std::mutex> lock(mutex);
        const auto& again = std::get<protocol::ProgressEvent>(events[said]);
        EXPECT_EQ(again.output, "lightmap");
        EXPECT_TRUE(again.again);
        EXPECT_EQ(again.progress.pass, 16);
        EXPECT_EQ(again.progress.rays, 1000u);
        EXPECT_GE(again.progress.seconds, 5.0 + EventHeartbeat::kPeriodSeconds);
        const auto count = [&](auto is) { return std::count_if(events.begin(), events.end(), is); };
        EXPECT_EQ(count([](const auto& e) { return std::holds_alternative<protocol::StartEvent>(e); }), 1);
        EXPECT_EQ(count([](const auto& e) { return std::holds_alternative<protocol::SnapshotEvent>(e); }), 1);
    }

    heartbeat.stop();
    size_t at_stop = 0;
    {
        const std::lock_guard<std::mutex> lock(mutex);
        at_stop = events.size();
    }
    std::this_thread::sleep_for(std::chrono::duration<double>(2.5 * EventHeartbeat::kPeriodSeconds));
    const std::lock_guard<std::mutex> lock(mutex);
    EXPECT_EQ(events.size(), at_stop) << "nothing after stop()";
}

// What the sink throws on a line said again (a closed pipe) reaches the
// bake's own thread at its next event, and nothing is said after.
TEST(EventHeartbeat, WhatTheSinkThrowsOnARepeatReachesTheBake) {
    std::atomic<int> calls{0};
    EventHeartbeat heartbeat([&](const protocol::WorkerEvent&) {
        if (++calls == 2) throw std::runtime_error("pipe closed");
    });
    const BakeEventSink emit = heartbeat.sink();
    emit(protocol::PrepareEvent{"methods", 0.0, 5.0});
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(30);
    while (calls < 2 && std::chrono::steady_clock::now() < until)
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
    ASSERT_EQ(calls, 2) << "the stage was said again";
    EXPECT_THROW(emit(protocol::SnapshotEvent{"lightmap", "x.exr", 1}), std::runtime_error);
    heartbeat.stop();
    EXPECT_EQ(calls, 2);
}

// The output registry (protocol/outputs.h) and the methods (issue #56): an
// output a job can ask for is one a method bakes, with the files it
// writes listed; a name no output has makes no method.
TEST(OutputRegistry, EveryOutputHasAMethodAndItsFiles) {
    ASSERT_FALSE(protocol::output_registry().empty());
    for (const protocol::OutputKind& o : protocol::output_registry()) {
        SCOPED_TRACE(o.name);
        EXPECT_NE(method_factory(o.name), nullptr) << "no method bakes it";
        EXPECT_FALSE(o.files.empty()) << "no file listed";
        EXPECT_EQ(protocol::find_output(o.name), &o);
    }
    EXPECT_EQ(method_factory("no-such-output"), nullptr);
}

TEST(SnapshotSchedule, FreeSnapshotsFollowTheDoublingPasses) {
    SnapshotSchedule schedule(0.1, 1e9);
    EXPECT_EQ(taken(schedule, 40, 0.001, 0.0), (std::vector<int>{1, 2, 4, 8, 16, 32}));
}

TEST(SnapshotSchedule, CostlySnapshotsKeepToTheBudget) {
    // A snapshot costs 1 s and a pass 1/8 s: after each, 9 s (72 passes)
    // without one, so that snapshots take at most 10% of the wall time; a
    // doubling held back is taken at the first pass after.
    SnapshotSchedule schedule(0.1, 1e9);
    const std::vector<int> passes = taken(schedule, 300, 0.125, 1.0);
    EXPECT_EQ(passes, (std::vector<int>{1, 73, 145, 256}));
    EXPECT_LE(double(passes.size()) * 1.0, 0.1 * 300 * 0.125 + 1.0);
}

TEST(SnapshotSchedule, ABusyWriterPostponesAndTimeAloneMakesOneDue) {
    SnapshotSchedule schedule(0.1, 10.0);
    EXPECT_TRUE(schedule.due(1, 0.0, true));
    EXPECT_FALSE(schedule.due(2, 0.1, false)) << "the writer is still writing pass 1";
    EXPECT_TRUE(schedule.due(3, 0.2, true)) << "pass 2's snapshot, held back";
    EXPECT_TRUE(schedule.due(4, 5.0, true)) << "pass 4 is a doubling of its own";
    EXPECT_FALSE(schedule.due(5, 14.5, true));
    EXPECT_TRUE(schedule.due(6, 15.0, true)) << "10 s after the last";
}

TEST(SnapshotSchedule, EveryIntervalSecondsBetweenDoublings) {
    SnapshotSchedule schedule(0.1, 10.0);
    // Passes of 1 s: doublings at 1, 2, 4, 8, 16, 32 and, between 16 and 32,
    // one at 26 (10 s after 16).
    EXPECT_EQ(taken(schedule, 40, 1.0, 0.0), (std::vector<int>{1, 2, 4, 8, 16, 26, 32}));
}

TEST(PassBatcher, DoublesWhileBatchesAreShortAndHalvesWhenLong) {
    PassBatcher batcher(8, 0.02);
    EXPECT_EQ(batcher.next(100), 1);
    std::vector<int> sizes;
    for (int i = 0; i < 5; ++i) {
        sizes.push_back(batcher.next(100));
        batcher.record(sizes.back(), 0.001 * sizes.back());  // 1 ms a pass
    }
    EXPECT_EQ(sizes, (std::vector<int>{1, 2, 4, 8, 8})) << "up to the method's most";
    batcher.record(8, 0.05);  // the passes got slower: 6 ms each
    EXPECT_EQ(batcher.next(100), 4);
    batcher.record(2, 0.001);  // a batch cut short by a limit says nothing of the size
    EXPECT_EQ(batcher.next(100), 4);
    EXPECT_EQ(batcher.next(3), 3) << "never past the limit";
    EXPECT_EQ(batcher.next(0), 1) << "a pass is always run";
    PassBatcher slow(64, 0.02);
    slow.record(1, 0.5);
    EXPECT_EQ(slow.next(100), 1) << "passes longer than the target run one at a time";
}

// A method whose passes are instant and count themselves.
class CountingMethod : public ProgressiveMethod {
public:
    explicit CountingMethod(int passes) { stop_.max_passes = passes; }
    std::string output() const override { return "counting"; }
    StopRule stop_rule() const override { return stop_; }
    nlohmann::json description() const override { return {}; }
    uint64_t rays_per_pass() const override { return 10; }
    PassStats step() override { return run_passes(1).back(); }
    std::vector<PassStats> run_passes(int count) override {
        batches.push_back(count);
        std::vector<PassStats> out;
        for (int k = 0; k < count; ++k) {
            ++stats_.pass;
            stats_.rays += 10;
            out.push_back(stats_);
        }
        return out;
    }
    int max_batch() const override { return 16; }
    SnapshotWrite snapshot(const std::filesystem::path&, const PassStats&) override { return {}; }
    MethodResult finish(const std::filesystem::path&, const PassStats&) override { return {}; }
    MethodState state() const override { throw std::logic_error("not used"); }
    void restore(const MethodState&) override {}

    std::vector<int> batches;

private:
    StopRule stop_;
    PassStats stats_;
};

TEST(RunProgressive, BatchesEndAtTheWantedPassesAndReportEveryPass) {
    CountingMethod method(100);
    std::vector<int> reported, batch_ends;
    int next_doubling = 1;
    const PassStats last = run_progressive(
        method,
        [&](const std::vector<PassStats>& passes) {
            for (const PassStats& p : passes) reported.push_back(p.pass);
            batch_ends.push_back(passes.back().pass);
            while (next_doubling <= passes.back().pass) next_doubling *= 2;
        },
        {}, [&] { return next_doubling; });
    EXPECT_EQ(last.pass, 100);
    EXPECT_EQ(last.rays, 1000u);
    ASSERT_EQ(reported.size(), 100u);
    for (int p = 0; p < 100; ++p) EXPECT_EQ(reported[size_t(p)], p + 1);
    for (int doubling : {1, 2, 4, 8, 16, 32, 64, 100})
        EXPECT_NE(std::find(batch_ends.begin(), batch_ends.end(), doubling), batch_ends.end())
            << "no batch ends on pass " << doubling;
    EXPECT_EQ(*std::max_element(method.batches.begin(), method.batches.end()), 16) << "instant passes batch up";
}

TEST(SnapshotWriter, WritesOffTheCallersThreadInOrderAndReportsWhenIdle) {
    SnapshotWriter writer;
    EXPECT_TRUE(writer.idle());
    std::promise<void> release;
    std::shared_future<void> released = release.get_future().share();
    const std::thread::id caller = std::this_thread::get_id();
    std::atomic<bool> off_thread{true};
    writer.submit("lightmap", 1, [&, released] {
        off_thread = off_thread && std::this_thread::get_id() != caller;
        released.wait();
        return std::vector<std::string>{"lightmap.pass-0001.exr"};
    });
    EXPECT_FALSE(writer.idle());
    EXPECT_TRUE(writer.take_written().empty()) << "nothing is announced before it is written";
    writer.submit("lightmap", 2, [] { return std::vector<std::string>{"lightmap.pass-0002.exr"}; });
    release.set_value();
    const std::vector<SnapshotWriter::Written> written = writer.drain();
    EXPECT_TRUE(off_thread);
    ASSERT_EQ(written.size(), 2u);
    EXPECT_EQ(written[0].pass, 1);
    EXPECT_EQ(written[0].files, std::vector<std::string>{"lightmap.pass-0001.exr"});
    EXPECT_EQ(written[1].pass, 2);
    EXPECT_TRUE(writer.idle());
}

TEST(SnapshotWriter, AFailedWriteReachesTheDriver) {
    SnapshotWriter writer;
    writer.submit("lightmap", 4, []() -> std::vector<std::string> {
        throw std::runtime_error("out/lightmap.pass-0004.exr: write failed (disk full?)");
    });
    try {
        writer.drain();
        FAIL() << "the failure was lost";
    } catch (const std::runtime_error& e) {
        EXPECT_NE(std::string(e.what()).find("lightmap.pass-0004.exr"), std::string::npos);
    }
    EXPECT_TRUE(writer.take_written().empty());  // reported once
}

}  // namespace
// The memory a bake may use: MemAvailable, and inside a container no more
// than what is left of its cgroup's memory.max (the estimate ignored the
// container's limit); an unlimited cgroup ("max") changes nothing.
TEST(AvailableMemory, TheContainersLimitBoundsMemAvailable) {
    const std::filesystem::path dir = std::filesystem::temp_directory_path() / ("lf-mem-" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir / "cg");
    std::ofstream(dir / "meminfo")
        << "MemTotal:       24000000 kB\nMemFree:        1000 kB\nMemAvailable:   20000000 kB\n"
           "HugePages_Total:       0\n";
    EXPECT_EQ(available_memory(dir / "meminfo", dir / "none"), 20000000ull * 1024);
    std::ofstream(dir / "cg" / "memory.max") << "max\n";
    std::ofstream(dir / "cg" / "memory.current") << "1000000\n";
    EXPECT_EQ(available_memory(dir / "meminfo", dir / "cg"), 20000000ull * 1024);
    std::ofstream(dir / "cg" / "memory.max") << "4000000000\n";
    EXPECT_EQ(available_memory(dir / "meminfo", dir / "cg"), 4000000000ull - 1000000ull);
    EXPECT_EQ(available_memory(dir / "nothing", dir / "cg"), 4000000000ull - 1000000ull);
    std::filesystem::remove_all(dir);
}

// The estimate grows with the sample points per texel (it counted texels
// only), and is at or above every peak measured (bake_settings.h).
TEST(AvailableMemory, TheEstimateCountsSubsamplesAndCoversTheMeasuredPeaks) {
    const uint64_t mb = 1ull << 20;
    EXPECT_GE(protocol::estimated_bake_bytes(1024 * 1024, 1), 462000ull * 1024);
    EXPECT_GE(protocol::estimated_bake_bytes(1024 * 1024, 2), 633000ull * 1024);
    EXPECT_GE(protocol::estimated_bake_bytes(1024 * 1024, 4), 1458000ull * 1024);
    EXPECT_GE(protocol::estimated_bake_bytes(512 * 512, 2), 220 * mb);
    EXPECT_GE(protocol::estimated_bake_bytes(2048 * 2048, 2), 2210 * mb);
    EXPECT_GT(protocol::estimated_bake_bytes(1024 * 1024, 4), 2 * protocol::estimated_bake_bytes(1024 * 1024, 1));
}

// Preparation's time left (the "prepare" events): every stage still to run,
// in prepare()'s order, from the sizes known; shrinking as stages pass;
// scaled by how this machine did on the stages behind once a second has
// passed; the atlas's stages only for a per-texel output.
TEST(PreparationEstimate, SumsTheStagesLeftAndScalesByTheStagesDone) {
    PreparationSize size;
    size.scene_bytes = 7'000'000;
    size.atlas = true;
    PreparationEstimate estimate(size);
    estimate.set_triangles(260'000, 0, false);
    estimate.set_sample_points(580'000);
    const std::vector<std::string> order = {"load",         "gpu",           "atlas",      "bvh",
                                            "double_sided", "texel_samples", "bvh_turned", "methods"};
    double previous = 1e30;
    for (size_t i = 0; i < order.size(); ++i) {
        const auto stages = estimate.stages_from(order[i]);
        ASSERT_EQ(stages.size(), order.size() - i);
        EXPECT_EQ(stages.front().first, order[i]);
        double sum = 0.0;
        for (const auto& [name, seconds] : stages) sum += seconds;
        const double left = *estimate.seconds_left(order[i], 0.5);  // under a second: no scaling
        EXPECT_DOUBLE_EQ(left, sum);
        EXPECT_LE(left, previous);
        previous = left;
    }
    EXPECT_GT(*estimate.seconds_left("methods", 0.0), 0.0) << "the relocation of 580k sample points takes time";
    // Twice as slow as predicted on what is done: twice the time left.
    double done = 0.0;
    for (const auto& [name, seconds] : estimate.stages_from("load"))
        if (name == "load" || name == "gpu" || name == "atlas") done += seconds;
    ASSERT_GT(done, 0.5);
    EXPECT_NEAR(*estimate.seconds_left("bvh", 2.0 * done), 2.0 * *estimate.seconds_left("bvh", 0.0), 1e-9);
    EXPECT_FALSE(estimate.seconds_left("no such stage", 1.0));
    // More sample points: a longer texel stage and relocation.
    PreparationEstimate larger = estimate;
    larger.set_sample_points(2 * 580'000);
    EXPECT_GT(*larger.seconds_left("texel_samples", 0.0), *estimate.seconds_left("texel_samples", 0.0));
    // A see-through material: the relocation's rays cost more.
    PreparationEstimate glass = estimate;
    glass.set_triangles(260'000, 0, true);
    EXPECT_GT(*glass.seconds_left("methods", 0.0), *estimate.seconds_left("methods", 0.0));
    // Per-vertex outputs only: no atlas, texel or relocation stage.
    size.atlas = false;
    PreparationEstimate vertices(size);
    vertices.set_triangles(260'000, 0, false);
    for (const auto& [name, seconds] : vertices.stages_from("load")) {
        if (name == "atlas" || name == "double_sided" || name == "texel_samples") {
            EXPECT_EQ(seconds, 0.0) << name;
        }
    }
}

}  // namespace lf
