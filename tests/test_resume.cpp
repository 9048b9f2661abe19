// Resuming an interrupted bake (issue #9, bake/method_state.h): the state
// file refuses what is not a whole state of this bake, saying why; and a
// bake stopped mid-pass-loop, as a killed worker stops, then resumed with
// `resume` (once in each output) ends with exactly the files of a bake that
// was never interrupted. Exactly, not statistically: every method's random
// numbers are keyed by (seed, pass, element), so the resumed passes trace the
// same rays; on one device the same rays give the same bits.
#include "atlas/atlas.h"
#include "bake/bake_job.h"
#include "bake/method_state.h"
#include "bake/radiosity_map_baker.h"
#include "bake/sh_transfer_baker.h"
#include "gpu_fixture.h"
#include "io/image_files.h"
#include "scene/gltf_loader.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cstring>
#include <functional>
#include <tuple>
#include <fstream>
#include <optional>
#include <sstream>

namespace lf {
namespace {

namespace fs = std::filesystem;

std::string file_bytes(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

void write_bytes(const fs::path& path, const std::string& bytes) {
    std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

MethodState example_state() {
    MethodState s;
    s.key = R"({"settings":{"seed":3}})";
    s.layout = 0x1234abcd5678ef00ull;
    s.stats.pass = 12;
    s.stats.rays = 123456789012ull;
    s.stats.seconds = 1.0 / 3.0;
    s.stats.error_estimate = 0.0625;
    s.counters = {4, 8, -1};
    s.buffers = {std::vector<std::byte>(40, std::byte{7}), {}, std::vector<std::byte>(3, std::byte{200})};
    s.files = {"lightmap.pass-0001.exr", "lightmap.pass-0008.exr"};
    return s;
}

// The reason a file is refused with.
std::string refusal(const fs::path& path) {
    try {
        read_method_state(path);
    } catch (const MethodStateMismatch& e) {
        return e.what();
    }
    return "(read without complaint)";
}

TEST(MethodStateFile, RoundTripsExactly) {
    const fs::path path = fs::temp_directory_path() / ("lf_state_" + std::to_string(::getpid())) / "x.state";
    const MethodState s = example_state();
    write_method_state(path, s);
    const MethodState r = read_method_state(path);
    EXPECT_EQ(r.key, s.key);
    EXPECT_EQ(r.layout, s.layout);
    EXPECT_EQ(r.stats.pass, s.stats.pass);
    EXPECT_EQ(r.stats.rays, s.stats.rays);
    EXPECT_EQ(r.stats.seconds, s.stats.seconds);  // time limits go on from the same total
    EXPECT_EQ(r.stats.error_estimate, s.stats.error_estimate);
    EXPECT_EQ(r.counters, s.counters);
    EXPECT_EQ(r.buffers, s.buffers);
    EXPECT_EQ(r.files, s.files);
    fs::remove_all(path.parent_path());
}

TEST(MethodStateFile, RefusesWhatIsNotAWholeStateSayingWhy) {
    const fs::path dir = fs::temp_directory_path() / ("lf_state_bad_" + std::to_string(::getpid()));
    const fs::path path = dir / "lightmap.state";
    write_method_state(path, example_state());
    const std::string good = file_bytes(path);

    write_bytes(path, good.substr(0, good.size() - 1));
    EXPECT_NE(refusal(path).find("lightmap.state: "), std::string::npos) << refusal(path);
    EXPECT_NE(refusal(path).find("shorter than its header says"), std::string::npos) << refusal(path);
    write_bytes(path, good.substr(0, 30));
    EXPECT_NE(refusal(path).find("truncated"), std::string::npos) << refusal(path);
    std::string flipped = good;
    flipped[good.size() - 12] ^= 0x10;  // in the last buffer
    write_bytes(path, flipped);
    EXPECT_NE(refusal(path).find("checksum does not match"), std::string::npos) << refusal(path);
    write_bytes(path, good + "x");
    EXPECT_NE(refusal(path).find("longer than its header says"), std::string::npos) << refusal(path);
    write_bytes(path, "EXR?" + good.substr(4));
    EXPECT_NE(refusal(path).find("not a lightfarm method state"), std::string::npos) << refusal(path);
    std::string huge = good;  // a header claiming a buffer larger than the file: nothing allocated
    const size_t at = huge.find("\"buffers\":[40");
    ASSERT_NE(at, std::string::npos);
    huge.replace(at + 11, 2, "99");
    write_bytes(path, huge);
    EXPECT_NE(refusal(path).find("shorter than its header says"), std::string::npos) << refusal(path);
    fs::remove(path);
    EXPECT_NE(refusal(path).find("cannot be read"), std::string::npos);
    fs::remove_all(dir);
}

// Bitwise equality of two read-back buffers.
template <class T>
bool same_bits(const std::vector<T>& a, const std::vector<T>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0;
}

// The bakers themselves, at a pass chosen here: a state taken after pass 6
// (in the middle of the epoch of passes 5-8, with texels converging under
// adaptive sampling) and restored into a new baker continues to the same
// bits as a baker that never stopped, under every scheme. With 4 passes per
// dispatch, a state after pass 66 is inside the cell of passes 65-68, whose
// passes read the map of pass 64, not the accumulators' values: it comes
// with the state.
TEST(ResumeBaker, ARadiosityMapRestoredMidEpochContinuesBitForBit) {
    test::gpu();
    Scene scene = load_scene(test::example_scene("cornell_box.gltf"));
    generate_lightmap_uvs(scene, {.resolution = 64});
    const TexelSamples texels = rasterize_texel_samples(scene, 64, 64, 2);
    const Tracer tracer(scene);
    for (const auto& [per_dispatch, stop] : {std::pair{1, 6}, std::pair{4, 66}})
        for (RadiosityScheme scheme : {RadiosityScheme::DoublingEpochs, RadiosityScheme::FinalGather,
                                       RadiosityScheme::Thesis, RadiosityScheme::PathTracing}) {
            SCOPED_TRACE(std::to_string(per_dispatch) + " passes per dispatch, stopped after pass " +
                         std::to_string(stop));
            RadiosityMapSettings settings;
            settings.scheme = scheme;
            settings.directional = true;
            settings.converged_texel_error = 0.2;  // some texels stop tracing: the active flags are state too
            settings.passes_per_dispatch = per_dispatch;
            RadiosityMapBaker whole(scene, texels, tracer, settings);
            for (int p = 0; p < stop; ++p) whole.step();
            const MethodState state = whole.state();
            const size_t map_buffers = scheme == RadiosityScheme::FinalGather   ? 2
                                       : scheme == RadiosityScheme::PathTracing ? 0  // it reads no map
                                                                                : 1;
            EXPECT_EQ(state.buffers.size(), 2 + (per_dispatch > 1 ? map_buffers : 0)) << "the map, inside a cell";
            RadiosityMapBaker resumed(scene, texels, tracer, settings);
            resumed.restore(state);
            if (per_dispatch > 1) {  // another device's count (auto follows the device) resumes it too
                RadiosityMapSettings one_per_dispatch = settings;
                one_per_dispatch.passes_per_dispatch = 1;
                RadiosityMapBaker elsewhere(scene, texels, tracer, one_per_dispatch);
                EXPECT_NO_THROW(elsewhere.restore(state));
                EXPECT_EQ(elsewhere.step().pass, stop + 1);
            }
            PassStats a, b;
            for (int p = stop; p < stop + 7; ++p) {
                a = whole.step();
                b = resumed.step();
            }
            const RadiosityMapBaker::Readback x = whole.read_back(), y = resumed.read_back();
            EXPECT_TRUE(same_bits(x.accumulators, y.accumulators)) << to_string(scheme);
            EXPECT_TRUE(same_bits(x.directional, y.directional)) << to_string(scheme);
            EXPECT_EQ(a.pass, b.pass);
            EXPECT_EQ(a.rays, b.rays) << to_string(scheme) << ": the same texels traced (adaptive sampling)";
            EXPECT_EQ(a.error_estimate, b.error_estimate) << to_string(scheme);
        }
    // A state of other texels is refused, and changes nothing.
    Scene other = load_scene(test::example_scene("cornell_box.gltf"));
    generate_lightmap_uvs(other, {.resolution = 48});
    const TexelSamples other_texels = rasterize_texel_samples(other, 48, 48, 2);
    RadiosityMapBaker elsewhere(other, other_texels, tracer, {});
    RadiosityMapBaker here(scene, texels, tracer, {});
    here.step();
    EXPECT_THROW(elsewhere.restore(here.state()), MethodStateMismatch);
    EXPECT_EQ(elsewhere.state().stats.pass, 0);
}

TEST(ResumeBaker, ShTransferRestoredMidBakeContinuesBitForBit) {
    test::gpu();
    const Scene scene = load_scene(test::example_scene("cornell_box.gltf"));
    const Tracer tracer(scene);
    ShTransferSettings settings;
    settings.samples_per_pass = 16;
    settings.bounces = 1;  // two blocks of sums, the bounce's a pass behind
    ShTransferBaker whole(scene, tracer, settings);
    for (int p = 0; p < 3; ++p) whole.step();
    ShTransferBaker resumed(scene, tracer, settings);
    resumed.restore(whole.state());
    PassStats a, b;
    for (int p = 3; p < 7; ++p) {
        a = whole.step();
        b = resumed.step();
    }
    const ShVertexTransfer x = whole.snapshot(), y = resumed.snapshot();
    EXPECT_TRUE(same_bits(x.coefficients, y.coefficients));
    EXPECT_TRUE(same_bits(x.standard_error, y.standard_error));
    EXPECT_EQ(a.pass, b.pass);
    EXPECT_EQ(a.rays, b.rays);
}

// A bake stopped like a killed worker: the sink throws at the progress of
// `output`'s pass `pass`. Its last state is on disk by then (the writer
// finishes what it was handed; the first snapshot, with its state, is
// always taken after pass 1), but which pass it holds depends on the
// snapshot schedule's clock: the assertions below allow any.
struct Stopped : std::runtime_error {
    Stopped() : std::runtime_error("stopped") {}
};

struct BakeRun {
    std::vector<protocol::WorkerEvent> events;
    std::optional<protocol::DoneEvent> done;
    // The start event (after preparation's events).
    const protocol::StartEvent& start() const {
        for (const auto& e : events)
            if (const auto* start = std::get_if<protocol::StartEvent>(&e)) return *start;
        throw std::runtime_error("the run had no start event");
    }
    // The passes of `output` this run traced.
    std::vector<int> passes(const std::string& output) const {
        std::vector<int> p;
        for (const auto& e : events)
            if (const auto* progress = std::get_if<protocol::ProgressEvent>(&e); progress && progress->output == output)
                p.push_back(progress->progress.pass);
        return p;
    }
};

BakeRun bake(const BakeJob& job, const std::string& stop_output = "", int stop_pass = 0) {
    BakeRun run;
    try {
        run.done = run_bake_job(job, [&](const protocol::WorkerEvent& e) {
            run.events.push_back(e);
            const auto* p = std::get_if<protocol::ProgressEvent>(&e);
            if (p && p->output == stop_output && p->progress.pass == stop_pass) throw Stopped();
        });
    } catch (const Stopped&) {
    }
    return run;
}

// Equal files: EXRs pixel for pixel in every channel (their headers hold
// times), anything else byte for byte.
::testing::AssertionResult same_file(const fs::path& a, const fs::path& b) {
    if (a.extension() != ".exr")
        return file_bytes(a) == file_bytes(b) ? ::testing::AssertionSuccess()
                                              : ::testing::AssertionFailure() << a.filename() << " differs";
    const FloatImage x = read_exr(a), y = read_exr(b);
    if (x.width != y.width || x.height != y.height || x.channels.size() != y.channels.size())
        return ::testing::AssertionFailure() << a.filename() << ": sizes or channels differ";
    for (const auto& [name, values] : x.channels) {
        const auto other = y.channels.find(name);
        if (other == y.channels.end() ||
            std::memcmp(values.data(), other->second.data(), values.size() * sizeof(float)) != 0)
            return ::testing::AssertionFailure() << a.filename() << ": channel " << name << " differs";
    }
    return ::testing::AssertionSuccess();
}

class Resume : public ::testing::Test {
protected:
    void SetUp() override {
        test::gpu();
        root = fs::temp_directory_path() / ("lf_resume_" + std::to_string(::getpid()));
        fs::remove_all(root);
        job.scene = test::example_scene("cornell_box.gltf");
        // Every output, each with state beyond one buffer: directional
        // lightmap (L1 sums), SH with a bounce (two blocks), two probes.
        job.settings = protocol::parse_bake_settings(
            {{"seed", 5},
             {"atlas", {{"res", 64}}},
             {"outputs",
              {{"lightmap", {{"passes", 24}, {"directional", true}}},
               {"sh", {{"sh_passes", 10}, {"sh_bands", 2}, {"sh_bounces", 1}}},
               {"probes",
                {{"probe_positions", {{{"position", {0.28, 0.27, 0.28}}}, {{"position", {0.1, 0.4, 0.2}}}}},
                 {"probe_res", 16},
                 {"probe_passes", 8}}},
               {"ao", {{"ao_passes", 12}, {"ao_distance", 0.3}}}}}});
    }
    void TearDown() override { fs::remove_all(root); }

    BakeJob job;
    fs::path root;
};

TEST_F(Resume, AnInterruptedBakeOfEveryOutputEndsWithTheFilesOfAnUninterruptedOne) {
    BakeJob whole = job;
    whole.out = root / "whole";
    const BakeRun uninterrupted = bake(whole);
    ASSERT_TRUE(uninterrupted.done);

    BakeJob cut = job;
    cut.out = root / "cut";
    // Stopped in the lightmap's passes, then in SH's, the probes' and AO's.
    const BakeRun first = bake(cut, "lightmap", 13);
    ASSERT_FALSE(first.done);
    EXPECT_TRUE(first.start().resumed.empty());
    cut.resume = true;
    const BakeRun second = bake(cut, "sh", 5);
    ASSERT_FALSE(second.done);
    const BakeRun third = bake(cut, "probes", 4);
    ASSERT_FALSE(third.done);
    const BakeRun fourth = bake(cut, "ao", 6);
    ASSERT_FALSE(fourth.done);
    const BakeRun last = bake(cut);
    ASSERT_TRUE(last.done);

    // Each run continued where the one before it saved its state.
    const int lightmap_from = second.start().resumed.at("lightmap").pass;
    EXPECT_GE(lightmap_from, 1);
    EXPECT_LE(lightmap_from, 13);
    EXPECT_EQ(second.passes("lightmap").front(), lightmap_from) << "the restored totals first";
    EXPECT_EQ(second.passes("lightmap")[1], lightmap_from + 1);
    EXPECT_EQ(second.start().not_resumed.at("sh"),
              "no state was saved (the earlier run stopped before its first "
              "snapshot)");
    EXPECT_EQ(third.start().resumed.at("lightmap").pass, 24) << "finished: reused, not baked again";
    EXPECT_EQ(third.passes("lightmap"), std::vector<int>{24});
    EXPECT_GE(third.start().resumed.at("sh").pass, 1);
    EXPECT_LE(third.start().resumed.at("sh").pass, 5);
    EXPECT_GE(fourth.start().resumed.at("probes").pass, 1);
    EXPECT_LE(fourth.start().resumed.at("probes").pass, 4);
    EXPECT_EQ(last.start().resumed.size(), 4u);
    EXPECT_GE(last.start().resumed.at("ao").pass, 1);
    EXPECT_LE(last.start().resumed.at("ao").pass, 6);
    EXPECT_EQ(last.passes("sh"), std::vector<int>{10});

    // The same result, rays and files as the bake never interrupted.
    EXPECT_EQ(last.done->progress.pass, uninterrupted.done->progress.pass);
    EXPECT_EQ(last.done->progress.rays, uninterrupted.done->progress.rays);
    EXPECT_EQ(last.done->final_files, uninterrupted.done->final_files);
    for (const auto& [output, file] : uninterrupted.done->final_files)
        EXPECT_TRUE(same_file(whole.out / file, cut.out / file)) << output;
    // scene.lit.glb: the uninterrupted bake makes it from the lightmap in
    // memory, the last run from the lightmap.exr an earlier run finished.
    for (const char* file : {"sh_transfer.half.bin", "env_sh.json", "probes.exr", "ao.exr", "scene.lit.glb"})
        EXPECT_TRUE(same_file(whole.out / file, cut.out / file)) << file;
    // Every file the runs wrote is named by the last one's done event (the
    // earlier runs' snapshots too), and no state is left.
    for (const auto& entry : fs::directory_iterator(cut.out)) {
        const std::string name = entry.path().filename().string();
        const auto& files = last.done->files;
        EXPECT_NE(std::find(files.begin(), files.end(), name), files.end()) << name << " is not in the done event";
    }
    EXPECT_FALSE(fs::exists(cut.out / protocol::kResumeDir));
}

// A stop request (the worker's SIGTERM: its job was cancelled) mid-bake:
// the driver takes one last snapshot of the pass it stands at, whatever the
// schedule says (issue #36: the job's newest snapshot was the schedule's
// last, pass 47 of a bake cancelled at pass 90), announces it, saves its
// state and throws BakeStopped; a resumed run continues after that pass.
TEST_F(Resume, AStopRequestEndsTheBakeWithASnapshotOfThePassItStoodAt) {
    job.settings.outputs.erase("sh");
    job.settings.outputs.erase("probes");
    job.settings.outputs.erase("ao");
    job.out = root / "stopped";
    clear_stop_request();
    std::vector<protocol::WorkerEvent> events;
    std::optional<BakeStopped> stopped;
    try {
        run_bake_job(job, [&](const protocol::WorkerEvent& e) {
            events.push_back(e);
            const auto* p = std::get_if<protocol::ProgressEvent>(&e);
            if (p && p->progress.pass == 13) {
                EXPECT_TRUE(request_stop()) << "a bake that passes takes its last snapshot";
            }
        });
    } catch (const BakeStopped& e) {
        stopped = e;
    }
    clear_stop_request();
    ASSERT_TRUE(stopped) << "the bake ran to its end";
    EXPECT_EQ(stopped->output, "lightmap");
    EXPECT_GE(stopped->pass, 13);
    EXPECT_LT(stopped->pass, 24);
    // Its last events: the pass it stopped at, then that pass's snapshot.
    int last_progress = 0, last_snapshot = 0;
    std::string last_file;
    for (const auto& e : events) {
        if (const auto* p = std::get_if<protocol::ProgressEvent>(&e)) last_progress = p->progress.pass;
        if (const auto* s = std::get_if<protocol::SnapshotEvent>(&e)) {
            last_snapshot = s->pass;
            last_file = s->file;
        }
    }
    EXPECT_EQ(last_progress, stopped->pass);
    EXPECT_EQ(last_snapshot, stopped->pass) << "the schedule alone took pass 8 last";
    EXPECT_TRUE(std::holds_alternative<protocol::SnapshotEvent>(events.back()));
    ASSERT_EQ(stopped->files, std::vector<std::string>{last_file});
    EXPECT_NO_THROW(read_exr(job.out / last_file));
    EXPECT_NE(std::string(stopped->what()).find("stopped on request at pass " + std::to_string(stopped->pass)),
              std::string::npos)
        << stopped->what();

    // Resumed, it continues after the pass it stopped at.
    job.resume = true;
    const BakeRun resumed = bake(job, "lightmap", stopped->pass + 1);
    EXPECT_EQ(resumed.start().resumed.at("lightmap").pass, stopped->pass);
    // Before the passes (preparation) a stop has nothing to save.
    EXPECT_FALSE(request_stop());
    clear_stop_request();
}

// Every key a resume depends on, changed alone: the saved states are
// another bake's, so each output starts from pass 0 and says why. Before
// the key held the job's settings, seed, environment and scene content, a
// lightmap or probes state resumed under another sky (or another scene with
// the same texels) and went on adding the other sky's sums.
TEST_F(Resume, AStateIsRestoredOnlyIntoTheBakeThatSavedIt) {
    job.settings.outputs.erase("sh");
    job.settings.outputs.erase("ao");
    job.settings.output("lightmap")->values["passes"] = 24;
    job.settings.env.sky = std::array<float, 3>{0.1f, 0.1f, 0.1f};
    const fs::path scene_dir = root / "scene";
    fs::create_directories(scene_dir);
    const std::string gltf = file_bytes(job.scene);
    write_bytes(scene_dir / "cornell_box.gltf", gltf);
    job.scene = scene_dir / "cornell_box.gltf";
    // A 4 x 2 Radiance map of one value (RGBE: mantissas 128, exponent e),
    // for the case where only the map's bytes change.
    const auto radiance_hdr = [](char exponent) {
        std::string hdr = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 4\n";
        for (int t = 0; t < 8; ++t) hdr += std::string("\x80\x80\x80") + exponent;
        return hdr;
    };
    const fs::path map = root / "sky.hdr";

    // Each change, and the outputs whose sums it changes (an output's own
    // settings are its key alone: the other output still resumes).
    using Change = std::function<void(BakeJob&)>;
    const std::vector<std::string> both = {"lightmap", "probes"};
    const std::vector<std::tuple<std::string, Change, std::vector<std::string>>> changes = {
        {"seed", [](BakeJob& j) { j.settings.seed = 6; }, both},
        {"env",
         [](BakeJob& j) {
             j.settings.env.sky = std::array<float, 3>{0.2f, 0.1f, 0.1f};
         },
         both},
        {"lightmap setting",
         [](BakeJob& j) { j.settings.output("lightmap")->values["light_samples"] = 2; },
         {"lightmap"}},
        {"probes setting", [](BakeJob& j) { j.settings.output("probes")->values["probe_passes"] = 9; }, {"probes"}},
        {"atlas", [](BakeJob& j) { j.settings.atlas.subsamples = 1; }, both},
        {"environment map's content",
         [&](BakeJob& j) {  // the same file name, other texels
             j.settings.env = {};
             j.settings.env.map_file = map.string();
             write_bytes(map, radiance_hdr(char(0x82)));
         },
         both},
        {"scene content",
         [&](BakeJob&) {  // the light's strength, same geometry and texels
             std::string other = gltf;
             const size_t at = other.find("\"emissiveStrength\": 17.0");
             ASSERT_NE(at, std::string::npos);
             other.replace(at, 24, "\"emissiveStrength\": 16.0");
             write_bytes(scene_dir / "cornell_box.gltf", other);
         },
         both},
    };
    for (const auto& [what, change, refused] : changes) {
        SCOPED_TRACE(what);
        write_bytes(job.scene, gltf);
        write_bytes(map, radiance_hdr(char(0x81)));
        BakeJob first = job;
        if (what == "environment map's content") {  // the first bake under the map, as it was
            first.settings.env = {};
            first.settings.env.map_file = map.string();
        }
        first.out = root / ("changed " + what);
        ASSERT_FALSE(bake(first, "probes", 3).done);
        // The same job resumes each output (the control)…
        BakeJob same = first;
        same.resume = true;
        fs::copy(first.out, root / ("same " + what), fs::copy_options::recursive);
        same.out = root / ("same " + what);
        const BakeRun again = bake(same, "probes", 4);
        EXPECT_EQ(again.start().resumed.count("lightmap"), 1u) << "the same bake resumes";
        EXPECT_EQ(again.start().resumed.count("probes"), 1u) << "the same bake resumes";
        // …and the job with one key changed resumes none of the outputs it changes.
        BakeJob changed = first;
        changed.resume = true;
        change(changed);
        const BakeRun other = bake(changed, "lightmap", 1);
        for (const std::string& output : both) {
            const bool refuses = std::find(refused.begin(), refused.end(), output) != refused.end();
            EXPECT_EQ(other.start().resumed.count(output), refuses ? 0u : 1u) << output;
            if (!refuses) continue;
            ASSERT_EQ(other.start().not_resumed.count(output), 1u) << output;
            EXPECT_NE(other.start().not_resumed.at(output).find("another bake's"), std::string::npos)
                << other.start().not_resumed.at(output);
        }
        if (std::find(refused.begin(), refused.end(), "lightmap") != refused.end()) {
            EXPECT_EQ(other.passes("lightmap").front(), 1);
        }
    }
}

// A resumed run of another seed ends with the pixels of a fresh bake of
// that seed; a damaged state is refused the same way.
TEST_F(Resume, AStateOfAnotherBakeIsNotRestored) {
    job.settings.output("lightmap")->values["passes"] = 24;
    job.settings.outputs.erase("sh");
    job.settings.outputs.erase("probes");
    job.settings.outputs.erase("ao");
    job.out = root / "seed5";
    ASSERT_FALSE(bake(job, "lightmap", 6).done);

    job.settings.seed = 6;
    job.resume = true;
    const BakeRun other = bake(job);
    ASSERT_TRUE(other.done);
    EXPECT_TRUE(other.start().resumed.empty());
    EXPECT_NE(other.start().not_resumed.at("lightmap").find("is another bake's"), std::string::npos)
        << other.start().not_resumed.at("lightmap");
    EXPECT_EQ(other.passes("lightmap").front(), 1);

    BakeJob fresh = job;
    fresh.out = root / "seed6";
    fresh.resume = false;
    ASSERT_TRUE(bake(fresh).done);
    EXPECT_TRUE(same_file(job.out / "lightmap.exr", fresh.out / "lightmap.exr"));

    fs::create_directories(job.out / protocol::kResumeDir);
    write_bytes(job.out / protocol::kResumeDir / "lightmap.state", "LFSTATE1 and then nothing sensible");
    const BakeRun damaged = bake(job);
    ASSERT_TRUE(damaged.done);
    EXPECT_NE(damaged.start().not_resumed.at("lightmap").find("lightmap.state: "), std::string::npos)
        << damaged.start().not_resumed.at("lightmap");
    EXPECT_TRUE(same_file(job.out / "lightmap.exr", fresh.out / "lightmap.exr"));
}

}  // namespace
}  // namespace lf
