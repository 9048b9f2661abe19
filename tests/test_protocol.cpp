// The job spec, status and event types of protocol/: validation names the bad
// field, unknown fields are errors, and everything survives a JSON round trip.
#include "job_spec.h"
#include "job_status.h"

#include <gtest/gtest.h>

namespace lf::protocol {
namespace {

using nlohmann::json;

// The SpecError message for a spec, or "" when it is valid.
std::string error_of(const json& j, const SpecLimits& limits = {}) {
    try {
        parse_job_spec(j, limits);
        return "";
    } catch (const SpecError& e) {
        return e.what();
    }
}

json valid_spec() {
    return {{"scene", "abc"}, {"outputs", {{"lightmap", {{"res", 256}, {"passes", 16}}}}}, {"seed", 7}};
}

TEST(JobSpec, ParsesAValidSpec) {
    const JobSpec spec = parse_job_spec(valid_spec());
    EXPECT_EQ(spec.scene, "abc");
    EXPECT_EQ(spec.seed, 7u);
    ASSERT_EQ(spec.outputs.count("lightmap"), 1u);
    EXPECT_EQ(spec.outputs.at("lightmap")["res"], 256);
    EXPECT_FALSE(spec.limits.max_seconds);
}

TEST(JobSpec, ResolutionOverTheLimitNamesTheField) {
    json j = valid_spec();
    j["outputs"]["lightmap"]["res"] = 100000;
    EXPECT_EQ(error_of(j), "lightmap.res: 100000 exceeds the limit 8192");
    SpecLimits small;
    small.caps["res"] = 512;
    j["outputs"]["lightmap"]["res"] = 1024;
    EXPECT_EQ(error_of(j, small), "lightmap.res: 1024 exceeds the limit 512");
}

TEST(JobSpec, UnknownFieldsAreErrors) {
    json j = valid_spec();
    j["colour"] = "blue";
    EXPECT_EQ(error_of(j).rfind("colour: unknown field", 0), 0u) << error_of(j);
    j = valid_spec();
    j["outputs"]["lightmap"]["resolution"] = 64;
    EXPECT_EQ(error_of(j).rfind("lightmap.resolution: unknown field", 0), 0u) << error_of(j);
    j = valid_spec();
    j["outputs"]["radiance"] = json::object();
    EXPECT_EQ(error_of(j).rfind("outputs.radiance: unknown output", 0), 0u) << error_of(j);
    j = valid_spec();
    j["limits"] = {{"gpu", 2}};
    EXPECT_EQ(error_of(j).rfind("limits.gpu: unknown field", 0), 0u) << error_of(j);
}

TEST(JobSpec, WrongTypesAndRangesNameTheField) {
    auto with = [](const std::string& key, const json& v) {
        json j = valid_spec();
        j["outputs"]["lightmap"][key] = v;
        return error_of(j);
    };
    EXPECT_EQ(with("res", "256"), "lightmap.res: must be a number, not a string");
    EXPECT_EQ(with("res", 256.5), "lightmap.res: must be an integer, not 256.5");
    EXPECT_EQ(with("res", 0), "lightmap.res: 0 is below the minimum 1");
    EXPECT_EQ(with("passes", -3), "lightmap.passes: -3 is below the minimum 1");
    EXPECT_EQ(with("target_error", 0), "lightmap.target_error: 0 is below the minimum (exclusive) 0");
    EXPECT_EQ(with("time_limit", 1e9), "lightmap.time_limit: 1000000000 exceeds the limit 14400");
    EXPECT_EQ(with("texel_density", 10), "lightmap.texel_density: cannot be given together with res");

    json j = valid_spec();
    j["seed"] = -1;
    EXPECT_EQ(error_of(j), "seed: must not be negative");
    j["seed"] = "one";
    EXPECT_EQ(error_of(j), "seed: must be a non-negative integer, not a string");
    j = valid_spec();
    j.erase("scene");
    EXPECT_EQ(error_of(j), "scene: is required");
    j = valid_spec();
    j["outputs"] = json::object();
    EXPECT_EQ(error_of(j), "outputs: must ask for at least one output");
    j = valid_spec();
    j["outputs"]["lightmap"] = 3;
    EXPECT_EQ(error_of(j), "lightmap: must be an object, not an integer");
    j = valid_spec();
    j["limits"] = {{"max_attempts", 100}};
    EXPECT_EQ(error_of(j), "limits.max_attempts: 100 exceeds the limit 10");
    EXPECT_EQ(error_of(json::array()), "must be an object, not an array");
}

TEST(JobSpec, SpecErrorCarriesTheField) {
    json j = valid_spec();
    j["outputs"]["lightmap"]["passes"] = 1e12;
    try {
        parse_job_spec(j);
        FAIL() << "accepted passes = 1e12";
    } catch (const SpecError& e) {
        EXPECT_EQ(e.field(), "lightmap.passes");
    }
}

TEST(JobSpec, RoundTripsThroughJson) {
    json j = valid_spec();
    j["limits"] = {{"max_seconds", 60.0}, {"max_attempts", 2}};
    const JobSpec spec = parse_job_spec(j);
    const JobSpec again = parse_job_spec(to_json(spec));
    EXPECT_EQ(to_json(spec), to_json(again));
    EXPECT_EQ(*again.limits.max_attempts, 2);
    EXPECT_DOUBLE_EQ(*again.limits.max_seconds, 60.0);
}

TEST(JobSpec, BakeIdentityIgnoresLimitsAndKeyOrder) {
    json a = valid_spec();
    json b = json::parse(R"({"seed": 7, "outputs": {"lightmap": {"passes": 16, "res": 256}}, "scene": "abc",
                             "limits": {"max_attempts": 1}})");
    EXPECT_EQ(bake_identity(parse_job_spec(a)), bake_identity(parse_job_spec(b)));
    b["seed"] = 8;
    EXPECT_NE(bake_identity(parse_job_spec(a)), bake_identity(parse_job_spec(b)));
}

TEST(JobSpec, BakeArgumentsAreTheCliOptions) {
    json j = valid_spec();
    j["outputs"]["lightmap"] = {{"texel_density", 12.5}, {"target_error", 0.01}, {"time_limit", 30}};
    const std::vector<std::string> args = bake_arguments(parse_job_spec(j));
    // Each output names itself (--lightmap, --sh), so a job asking for both bakes both.
    const std::vector<std::string> expected = {"--lightmap", "--texel-density", "12.5", "--target-error", "0.01",
                                               "--time-limit", "30", "--seed", "7"};
    EXPECT_EQ(args, expected);
}

TEST(JobSpec, CliOptionsBecomeOutputs) {
    auto outputs = outputs_from_bake_options({{"--res", "128"}, {"--target-error", "0.02"}});
    ASSERT_EQ(outputs.count("lightmap"), 1u);
    EXPECT_EQ(outputs["lightmap"]["res"], 128);
    EXPECT_DOUBLE_EQ(outputs["lightmap"]["target_error"].get<double>(), 0.02);
    EXPECT_EQ(outputs_from_bake_options({}).at("lightmap"), json::object());
    try {
        outputs_from_bake_options({{"--passes", "many"}});
        FAIL();
    } catch (const SpecError& e) {
        EXPECT_EQ(std::string(e.what()), "--passes: 'many' is not an integer");
    }
    // Every flag the catalog knows is one the CLI accepts, and back.
    for (const std::string& flag : bake_option_flags()) EXPECT_EQ(flag.rfind("--", 0), 0u);
}

TEST(JobStatus, RoundTripsThroughJson) {
    JobStatus s;
    s.id = "j1";
    s.scene = "abc";
    s.state = JobState::Failed;
    s.spec = valid_spec();
    s.progress.pass = 3;
    s.progress.rays = 1u << 20;
    s.progress.seconds = 1.5;
    s.progress.error_estimate = 0.25;
    s.attempts = 3;
    s.max_attempts = 3;
    s.error = "bake failed after 3 attempts";
    s.cause = "worker killed by signal 9";
    s.created_at = 100;
    const JobStatus t = status_from_json(to_json(s));
    EXPECT_EQ(to_json(t), to_json(s));
    EXPECT_EQ(to_json(s)["started_at"], nullptr);
    EXPECT_TRUE(is_final(JobState::Cancelled));
    EXPECT_FALSE(is_final(JobState::Running));
    EXPECT_EQ(parse_job_state("running"), JobState::Running);
    EXPECT_FALSE(parse_job_state("paused"));
}

TEST(JobStatus, EtaFollowsTheStoppingRules) {
    Progress p;
    p.pass = 4;
    p.seconds = 2.0;  // 0.5 s per pass
    EXPECT_FALSE(estimate_eta(json::object(), p));
    EXPECT_DOUBLE_EQ(*estimate_eta({{"passes", 10}}, p), 3.0);
    EXPECT_DOUBLE_EQ(*estimate_eta({{"passes", 10}, {"time_limit", 3}}, p), 1.0);
    p.error_estimate = 0.02;  // twice the target: 4x the passes, 12 more
    EXPECT_DOUBLE_EQ(*estimate_eta({{"target_error", 0.01}}, p), 6.0);
}

TEST(Sse, FormatsAndParsesInAnyChunking) {
    const std::vector<JobEvent> events = {{1, "progress", {{"pass", 1}}},
                                          {2, "snapshot", {{"file", "lightmap.pass-0001.exr"}}},
                                          {3, "done", {{"files", {"lightmap.exr"}}}}};
    std::string stream = ": hello\n\n";
    for (const JobEvent& e : events) stream += format_sse(e);
    for (size_t chunk : {size_t(1), size_t(7), stream.size()}) {
        SseParser parser;
        std::vector<JobEvent> got;
        for (size_t i = 0; i < stream.size(); i += chunk)
            for (JobEvent& e : parser.feed(stream.substr(i, chunk))) got.push_back(e);
        ASSERT_EQ(got.size(), events.size()) << "chunk " << chunk;
        for (size_t i = 0; i < events.size(); ++i) {
            EXPECT_EQ(got[i].id, events[i].id);
            EXPECT_EQ(got[i].type, events[i].type);
            EXPECT_EQ(got[i].data, events[i].data);
        }
    }
    EXPECT_TRUE(is_final_event("done"));
    EXPECT_FALSE(is_final_event("snapshot"));
}

}  // namespace
}  // namespace lf::protocol
