// protocol/: the one settings catalog and its one validity rule, the job
// spec, the engine-server contract (worker events, scene summary), job status
// and events. Validation names the bad field (or the CLI flag), unknown names
// are errors, everything survives a JSON round trip, and the OpenAPI document
// and the README's option table say exactly what the catalog says.
#include "bake_settings.h"
#include "display_tone.h"
#include "job_spec.h"
#include "job_status.h"
#include "lightmap_rgbm.h"
#include "percent_decoding.h"
#include "worker_protocol.h"

#include <gtest/gtest.h>

#include <limits>

#include <algorithm>
#include <regex>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <set>
#include <sstream>

namespace lf::protocol {
namespace {

using nlohmann::json;

// ---------------------------------------------------------------------------
// Helpers

// The SpecError of a job spec ("field: reason"), or "" when it is valid.
std::string error_of(const json& j, const SpecLimits& limits = {}) {
    try {
        parse_job_spec(j, limits);
        return "";
    } catch (const SpecError& e) {
        return e.what();
    }
}

// The field a job spec is refused for, or "" when it is valid.
std::string field_of(const json& j, const SpecLimits& limits = {}) {
    try {
        parse_job_spec(j, limits);
        return "";
    } catch (const SpecError& e) {
        return e.field().empty() ? "(none)" : e.field();
    }
}

bool starts_with(const std::string& s, const std::string& prefix) { return s.rfind(prefix, 0) == 0; }

json valid_spec() {
    return {{"scene", "abc"}, {"outputs", {{"lightmap", {{"passes", 16}}}}}, {"atlas", {{"res", 256}}}, {"seed", 7}};
}

// A spec asking only for sh with one setting.
json sh_spec(const std::string& key, const json& value) {
    return {{"scene", "abc"}, {"outputs", {{"sh", {{key, value}}}}}};
}

// bake_json_from_flags' SpecError as "what", or "" when it was accepted.
std::string flag_error_of(const std::map<std::string, std::string>& flags, const json& base = json::object()) {
    try {
        bake_json_from_flags(flags, base);
        return "";
    } catch (const SpecError& e) {
        return e.what();
    }
}

// The repository's root, from this file's path (tests/test_protocol.cpp).
std::filesystem::path repo_root() { return std::filesystem::path(__FILE__).parent_path().parent_path(); }

std::string read_text(const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

// ---------------------------------------------------------------------------
// The catalog

// Snapshot names: what the engine writes, what clients tell from final files.
// RGBM (protocol/lightmap_rgbm.h): every value comes back within half a step
// of its pixel's scale, range * a / 255², and the brightest channel within
// 0.4% from range / 255 up, as the header promises.
// How lightfarm shows light (protocol/display_tone.h), against closed forms:
// the automatic exposure puts the lit values' geometric mean luminance at
// 0.18; the filmic curve is three.js's ACESFilmicToneMapping, whose two
// matrices keep grey grey (their rows sum to 1), so at linear 0.6 and
// exposure 1 it is Hill's fit at 1, (1.0245786 - 0.000090537) / (0.983729 +
// 0.432951 + 0.238081); sRGB's transfer at its knee and at one half.
TEST(DisplayTone, ExposureCurveAndSrgbAreTheViewsClosedForms) {
    EXPECT_NEAR(protocol::automatic_exposure({0.5f, 0.5f, 0.5f, 2.0f, 2.0f, 2.0f}), 0.18, 1e-6);
    const float nan = std::nanf("");
    EXPECT_NEAR(protocol::automatic_exposure({0.25f, 0.25f, 0.25f, 0, 0, 0, nan, nan, nan}), 0.72, 1e-5)
        << "unlit and non-finite values do not count";
    EXPECT_EQ(protocol::automatic_exposure({}), 1.0);
    EXPECT_EQ(protocol::automatic_exposure({0, 0, 0}), 1.0);
    EXPECT_NEAR(protocol::automatic_exposure({2.0f, 2.0f, 2.0f, 1e-4f, 1e-4f, 1e-4f}), 0.09, 1e-6)
        << "a texel below kExposureFloor of the brightest (RGBM's black) does not count";
    EXPECT_NEAR(protocol::automatic_exposure({2.0f, 2.0f, 2.0f, 4e-4f, 4e-4f, 4e-4f}), 0.18 / std::sqrt(8e-4), 1e-4)
        << "one above it does";

    const double fit_at_one = (1.0245786 - 0.000090537) / (0.983729 + 0.432951 + 0.238081);
    for (float c : protocol::aces_filmic({0.6f, 0.6f, 0.6f}, 1.0f)) EXPECT_NEAR(c, fit_at_one, 2e-5);
    for (float c : protocol::aces_filmic({0.3f, 0.3f, 0.3f}, 2.0f)) EXPECT_NEAR(c, fit_at_one, 2e-5) << "exposure";
    for (float c : protocol::aces_filmic({0, 0, 0}, 1.0f)) EXPECT_NEAR(c, 0.0, 1e-4);
    for (float c : protocol::aces_filmic({1e6f, 1e6f, 1e6f}, 1.0f)) EXPECT_EQ(c, 1.0f) << "saturates at white";
    for (float c : protocol::aces_filmic({nan, -1.0f, 0.0f}, 1.0f)) EXPECT_NEAR(c, 0.0, 1e-4);
    float previous = -1.0f;
    for (float v = 0.0f; v < 20.0f; v += 0.05f) {  // grey stays grey, and brighter is brighter up to white
        const std::array<float, 3> c = protocol::aces_filmic({v, v, v}, 1.0f);
        EXPECT_NEAR(c[0], c[1], 1e-4);
        EXPECT_NEAR(c[1], c[2], 1e-4);
        EXPECT_TRUE(c[1] > previous || c[1] == 1.0f) << v << ": " << c[1] << " after " << previous;
        previous = c[1];
    }
    const std::array<float, 3> red = protocol::aces_filmic({1.0f, 0.0f, 0.0f}, 1.0f);
    EXPECT_GT(red[0], 10.0f * std::max(red[1], red[2])) << "a colour keeps its hue";

    EXPECT_EQ(protocol::encode_srgb8(0.0f), 0);
    EXPECT_EQ(protocol::encode_srgb8(1.0f), 255);
    EXPECT_EQ(protocol::encode_srgb8(2.0f), 255);
    EXPECT_EQ(protocol::encode_srgb8(-1.0f), 0);
    EXPECT_EQ(protocol::encode_srgb8(nan), 0);
    EXPECT_EQ(protocol::encode_srgb8(0.0031308f), 10);  // 12.92 x 0.0031308 x 255 = 10.3
    EXPECT_EQ(protocol::encode_srgb8(0.5f), 188);       // (1.055 x 0.5^(1/2.4) - 0.055) x 255 = 187.5
}

TEST(Rgbm, RoundTripsWithinHalfAStepOverItsDynamicRange) {
    std::vector<float> rgb;
    for (double v = 1e-5; v <= 20.0; v *= 1.07) {
        rgb.insert(rgb.end(), {float(v), float(v * 0.5), float(v * 0.11)});
    }
    rgb.insert(rgb.end(), {0.0f, -1.0f, std::nanf("")});  // stored as 0
    const int width = int(rgb.size() / 3);
    const protocol::RgbmImage image = protocol::encode_rgbm(rgb, width, 1);
    EXPECT_FLOAT_EQ(image.range, *std::max_element(rgb.begin(), rgb.end() - 3)) << "the range is the brightest value";
    const std::vector<float> back = protocol::decode_rgbm(image);
    ASSERT_EQ(back.size(), rgb.size());
    for (int p = 0; p < width - 1; ++p) {
        const float largest = rgb[3 * size_t(p)];
        const float step = image.range * float(image.rgba[4 * size_t(p) + 3]) / 255.0f / 255.0f;
        EXPECT_LE(step, 1.0001f * (largest + image.range / 255.0f) / 255.0f)
            << "the multiplier rounds up by at most one step";
        for (int k = 0; k < 3; ++k)
            EXPECT_NEAR(back[3 * size_t(p) + size_t(k)], rgb[3 * size_t(p) + size_t(k)], 0.5001f * step) << p;
        if (largest >= image.range / 255.0f) {
            EXPECT_NEAR(back[3 * size_t(p)] / largest, 1.0f, 0.5f / 127.0f) << largest;
        }
    }
    for (size_t k = back.size() - 3; k < back.size(); ++k) EXPECT_EQ(back[k], 0.0f);
    const std::string png = protocol::rgbm_png(image);
    EXPECT_EQ(png.substr(1, 3), "PNG");
    EXPECT_THROW(protocol::encode_rgbm(rgb, width + 1, 1), std::invalid_argument);
}

// One percent-decoding for the loader, the server's upload check and the
// CLI's upload (issue #56: three copies, one of which threw on "%zz"):
// every byte, escaped in either case or not at all, decodes to itself
// (drawn strings, seed printed); '+' stays '+'; a malformed escape is
// refused, never guessed.
TEST(PercentDecoding, EveryByteRoundTripsAndMalformedEscapesAreRefused) {
    std::mt19937 rng(56);
    std::printf("  seed 56\n");
    for (int trial = 0; trial < 500; ++trial) {
        std::string plain, escaped;
        for (int k = int(rng() % 40); k > 0; --k) {
            const unsigned char c = static_cast<unsigned char>(rng() % 256);
            plain += char(c);
            char hex[4];
            std::snprintf(hex, sizeof hex, rng() % 2 ? "%%%02X" : "%%%02x", c);
            escaped += c != '%' && rng() % 2 ? std::string(1, char(c)) : std::string(hex);
        }
        const std::optional<std::string> decoded = percent_decode(escaped);
        ASSERT_TRUE(decoded) << escaped;
        EXPECT_EQ(*decoded, plain);
    }
    EXPECT_EQ(percent_decode("a+b%20c"), "a+b c");
    EXPECT_EQ(percent_decode(""), "");
    for (const char* bad : {"%", "a%", "%4", "a%4", "%zz", "%g0", "%0g", "%%41"})
        EXPECT_FALSE(percent_decode(bad)) << bad;
}

TEST(SnapshotNames, AreStemPassNumberExtension) {
    EXPECT_EQ(snapshot_file_name("lightmap", 4, "exr"), "lightmap.pass-0004.exr");
    EXPECT_EQ(snapshot_file_name("sh_transfer", 16384, "bin"), "sh_transfer.pass-16384.bin");
    EXPECT_TRUE(is_snapshot_file("lightmap.pass-0004.exr"));
    EXPECT_TRUE(is_snapshot_file(snapshot_file_name("probes", 12, "json")));
    EXPECT_EQ(snapshot_pattern("lightmap.pass-0004.exr"), "lightmap.pass-NNNN.exr");
    EXPECT_EQ(snapshot_pattern("sh_transfer.pass-16384.bin"), "sh_transfer.pass-NNNN.bin");
    EXPECT_EQ(snapshot_pattern("lightmap.exr"), "lightmap.exr");
    for (const char* final_file : {"lightmap.exr", "manifest.json", "scene.lightmapped.glb", "probes.exr",
                                   "lightmap.pass-.exr", "lightmap.pass-12", "x.pass-1a.exr"})
        EXPECT_FALSE(is_snapshot_file(final_file)) << final_file;
}

TEST(Catalog, NamesFlagsAndFieldsAreUniqueAndConsistent) {
    std::set<std::string> flags, fields;
    for (const Setting& s : setting_catalog()) {
        EXPECT_TRUE(flags.insert(s.flag()).second) << s.flag();
        EXPECT_TRUE(fields.insert(s.field()).second) << s.field();
        EXPECT_EQ(find_setting(s.group, s.name), &s);
        EXPECT_EQ(find_setting_by_flag(s.flag()), &s);
        EXPECT_FALSE(s.help.empty()) << s.field();
        const bool known_group = s.group.empty() || s.group == "atlas" ||
                                 std::count(output_names().begin(), output_names().end(), s.group) == 1;
        EXPECT_TRUE(known_group) << s.field();
        if (s.type == SettingType::Choice) {
            ASSERT_FALSE(s.choices.empty()) << s.field();
            EXPECT_EQ(s.default_value, s.choices.front()) << s.field();
        }
        if (s.accepts_auto) {
            EXPECT_EQ(s.default_value, "auto") << s.field();
        }
        if (s.type == SettingType::Integer || s.type == SettingType::Number) {
            EXPECT_LT(s.min, s.max) << s.field();
        }
    }
    EXPECT_EQ(find_setting("lightmap", "passes")->field(), "lightmap.passes");
    EXPECT_EQ(find_setting("atlas", "res")->field(), "atlas.res");
    EXPECT_EQ(find_setting("", "seed")->field(), "seed");
    EXPECT_EQ(find_setting("lightmap", "stitch")->flag(), "--no-stitch");
    EXPECT_EQ(find_setting("sh", "sh_per_texel")->flag(), "--sh-per-texel");
    EXPECT_EQ(find_setting("atlas", "texel_density")->flag(), "--texel-density");
    EXPECT_EQ(find_setting("lightmap", "resolution"), nullptr);
    EXPECT_EQ(find_setting_by_flag("--stitch"), nullptr);
}

TEST(Catalog, BakeFlagsAreTheOutputsAndEverySetting) {
    const std::vector<std::pair<std::string, bool>> listed = bake_flags();
    std::map<std::string, bool> flags(listed.begin(), listed.end());
    EXPECT_EQ(flags.size(), listed.size()) << "a flag is listed twice";
    for (const std::string& o : output_names()) EXPECT_EQ(flags.at("--" + o), false) << o;
    size_t on_by_default = 0;
    for (const Setting& s : setting_catalog()) {
        EXPECT_EQ(flags.at(s.flag()), s.type != SettingType::Flag) << s.flag();
        if (s.type == SettingType::Flag && s.default_value == true) {
            // Its positive form too (`--denoise` beside `--no-denoise`): it says the default.
            EXPECT_EQ(flags.at("--" + s.flag().substr(5)), false) << s.flag();
            ++on_by_default;
        }
    }
    EXPECT_EQ(flags.size(), output_names().size() + setting_catalog().size() + on_by_default);
}

// A flag that was off by default and is now on (`--denoise`) is still taken
// as written then: it sets the default; its --no- form turns it off.
TEST(Catalog, AnOnByDefaultFlagTakesBothForms) {
    EXPECT_EQ(bake_json_from_flags({{"--denoise", ""}})["outputs"]["lightmap"]["denoise"], true);
    EXPECT_EQ(bake_json_from_flags({{"--no-denoise", ""}})["outputs"]["lightmap"]["denoise"], false);
    EXPECT_EQ(bake_json_from_flags({{"--stitch", ""}})["outputs"]["lightmap"]["stitch"], true);
    EXPECT_THROW(bake_json_from_flags({{"--no-directional", ""}}), SpecError) << "off by default: no --no- form";
}

// ---------------------------------------------------------------------------
// parse_bake_settings / parse_job_spec: the one validity rule

TEST(JobSpec, ParsesAValidSpec) {
    const JobSpec spec = parse_job_spec(valid_spec());
    EXPECT_EQ(spec.scene, "abc");
    EXPECT_EQ(spec.bake.seed, 7u);
    ASSERT_TRUE(spec.bake.output("lightmap"));
    EXPECT_FALSE(spec.bake.output("sh"));
    EXPECT_EQ(spec.bake.output("lightmap")->stop().passes, 16);
    EXPECT_EQ(spec.bake.atlas.res, 256);
    EXPECT_FALSE(spec.bake.atlas.texel_density);
    EXPECT_FALSE(spec.limits.max_seconds);
    EXPECT_FALSE(spec.limits.max_attempts);
    EXPECT_FALSE(spec.bake.env.given());
}

TEST(JobSpec, DefaultsComeFromTheCatalog) {
    json every_output = json::object();
    for (const std::string& o : output_names()) every_output[o] = json::object();
    const BakeSettings b = parse_bake_settings({{"outputs", every_output}});
    const json j = to_json(b);
    // Every setting of every output, the atlas and the job, with the catalog's default.
    for (const Setting& s : setting_catalog()) {
        const json* at = nullptr;
        if (s.group.empty()) at = j.contains(s.name) ? &j[s.name] : nullptr;
        else if (s.group == "atlas") at = &j["atlas"].at(s.name);
        else at = &j["outputs"][s.group].at(s.name);
        if (s.default_value.is_null()) {
            EXPECT_EQ(at, nullptr) << s.field() << " has no default, so no value";
            continue;
        }
        ASSERT_NE(at, nullptr) << s.field();
        EXPECT_EQ(*at, s.default_value) << s.field();
    }
    // And the typed values agree.
    ASSERT_TRUE(b.output("lightmap") && b.output("sh"));
    EXPECT_EQ(b.output("lightmap")->stop().passes, find_setting("lightmap", "passes")->default_value.get<int>());
    EXPECT_EQ(b.output("lightmap")->choice("scheme"), "epochs");
    EXPECT_EQ(b.output("lightmap")->choice("light_sampling"), "mis");
    EXPECT_TRUE(b.output("lightmap")->flag("stitch"));
    EXPECT_EQ(b.output("sh")->values["sh_bands"], "auto") << "sh_bands defaults to auto";
    EXPECT_EQ(b.output("sh")->choice("sh_window"), "none");
    EXPECT_EQ(b.output("sh")->stop().passes, find_setting("sh", "sh_passes")->default_value.get<int>());
    EXPECT_FALSE(b.atlas.res);
    EXPECT_FALSE(b.atlas.texel_density);
    EXPECT_EQ(b.atlas.subsamples, find_setting("atlas", "subsamples")->default_value.get<int>());
    EXPECT_EQ(b.seed, find_setting("", "seed")->default_value.get<uint32_t>());
}

// The edge values of issue #10: the server once accepted these and the worker refused them.
TEST(JobSpec, EdgeValuesAreRefusedWithTheFieldNamed) {
    EXPECT_EQ(error_of(sh_spec("sh_bands", 0)), "sh.sh_bands: 0 is below the minimum 1");
    EXPECT_EQ(error_of(sh_spec("sh_bands", 9)), "sh.sh_bands: 9 exceeds the maximum 4");
    EXPECT_EQ(error_of(sh_spec("sh_bounces", 7)), "sh.sh_bounces: 7 exceeds the maximum 4");
    EXPECT_EQ(error_of(sh_spec("sh_bounces", -1)), "sh.sh_bounces: -1 is below the minimum 0");
    EXPECT_EQ(field_of(sh_spec("sh_bands", "4")), "sh.sh_bands");
    EXPECT_EQ(field_of(sh_spec("sh_bands", 2.5)), "sh.sh_bands");
    EXPECT_EQ(field_of(sh_spec("sh_window", "hamming")), "sh.sh_window");
    EXPECT_EQ(field_of(sh_spec("sh_per_texel", 1)), "sh.sh_per_texel");
    EXPECT_EQ(field_of(sh_spec("sh_occluders", json::array({0, -1}))), "sh.sh_occluders");
    EXPECT_EQ(field_of(sh_spec("sh_receivers", "0,1")), "sh.sh_receivers");
    for (int bands = 1; bands <= 4; ++bands) EXPECT_EQ(error_of(sh_spec("sh_bands", bands)), "") << bands;
    EXPECT_EQ(error_of(sh_spec("sh_bounces", 4)), "");

    json j = valid_spec();
    j["seed"] = 4294967296ull;
    EXPECT_EQ(error_of(j), "seed: 4294967296 exceeds the maximum 4294967295");
    j["seed"] = -1;
    EXPECT_EQ(error_of(j), "seed: -1 is below the minimum 0");
    j["seed"] = "one";
    EXPECT_EQ(field_of(j), "seed");
    j["seed"] = 1.5;
    EXPECT_EQ(field_of(j), "seed");
    j["seed"] = 4294967295ull;
    EXPECT_EQ(error_of(j), "");
    EXPECT_EQ(parse_job_spec(j).bake.seed, 4294967295u);
    j["seed"] = 0;
    EXPECT_EQ(parse_job_spec(j).bake.seed, 0u);
}

TEST(JobSpec, AutoIsAValueOfItsOwn) {
    const JobSpec spec = parse_job_spec(sh_spec("sh_bands", "auto"));
    ASSERT_TRUE(spec.bake.output("sh"));
    EXPECT_FALSE(spec.bake.output("sh")->integer_or_auto("sh_bands"));
    EXPECT_EQ(to_json(spec)["outputs"]["sh"]["sh_bands"], "auto");
    EXPECT_EQ(parse_job_spec(sh_spec("sh_bands", 3)).bake.output("sh")->integer("sh_bands"), 3);
    EXPECT_EQ(to_json(parse_job_spec(sh_spec("sh_bands", 3)))["outputs"]["sh"]["sh_bands"], 3);
    // "auto" only where the catalog says so, and no other word.
    EXPECT_EQ(field_of(sh_spec("sh_bands", "Auto")), "sh.sh_bands");
    EXPECT_EQ(field_of(sh_spec("sh_bounces", "auto")), "sh.sh_bounces");
    json j = valid_spec();
    j["atlas"] = {{"res", "auto"}, {"texel_density", "auto"}};
    const JobSpec a = parse_job_spec(j);
    EXPECT_FALSE(a.bake.atlas.res);
    EXPECT_FALSE(a.bake.atlas.texel_density);
    EXPECT_EQ(to_json(a)["atlas"]["res"], "auto");
    EXPECT_EQ(to_json(a)["atlas"]["texel_density"], "auto");
    j["atlas"] = {{"texel_density", 12.5}};
    EXPECT_DOUBLE_EQ(*parse_job_spec(j).bake.atlas.texel_density, 12.5);
    EXPECT_EQ(to_json(parse_job_spec(j))["atlas"]["res"], "auto");
    j["outputs"]["lightmap"]["passes"] = "auto";
    EXPECT_EQ(field_of(j), "lightmap.passes");
}

// An atlas the engine sizes (res auto, or from texel_density) keeps to a
// server's res limit too: the limit below the engine's own 4096 is written
// into the spec the worker receives, and a larger max_res is refused.
TEST(JobSpec, AServersResLimitBoundsTheAtlasesTheEngineSizes) {
    json j = valid_spec();
    j["atlas"] = json::object();
    SpecLimits limits;
    limits.caps["res"] = 1024;
    const JobSpec capped = parse_job_spec(j, limits);
    EXPECT_EQ(capped.bake.atlas.max_res, 1024);
    EXPECT_EQ(to_json(capped)["atlas"]["max_res"], 1024) << "the worker reads it from the stored spec";
    EXPECT_EQ(parse_job_spec(to_json(capped)).bake.atlas.max_res, 1024);
    j["atlas"]["max_res"] = 512;
    EXPECT_EQ(parse_job_spec(j, limits).bake.atlas.max_res, 512) << "a lower one of the job's own stays";
    j["atlas"]["max_res"] = 2048;
    EXPECT_EQ(error_of(j, limits), "atlas.max_res: 2048 exceeds this server's limit 1024");
    j["atlas"]["max_res"] = 128;
    EXPECT_EQ(error_of(j), "atlas.max_res: 128 is below the minimum 256");
    // Without a limit below 4096 it stays auto: the engine's own bound.
    j["atlas"].erase("max_res");
    EXPECT_FALSE(parse_job_spec(j).bake.atlas.max_res);
    EXPECT_EQ(to_json(parse_job_spec(j))["atlas"]["max_res"], "auto");
    limits.caps["res"] = 100;  // below the default atlas: that atlas, no smaller
    EXPECT_EQ(parse_job_spec(j, limits).bake.atlas.max_res, 256);
}

TEST(JobSpec, ResAndTexelDensityTogetherAreRefused) {
    json j = valid_spec();
    j["atlas"] = {{"res", 256}, {"texel_density", 10}};
    EXPECT_EQ(field_of(j), "atlas.texel_density");
    EXPECT_NE(error_of(j).find("atlas.res"), std::string::npos) << error_of(j);
    // One of them "auto" is not both.
    j["atlas"] = {{"res", "auto"}, {"texel_density", 10}};
    EXPECT_EQ(error_of(j), "");
    j["atlas"] = {{"res", 256}, {"texel_density", "auto"}};
    EXPECT_EQ(error_of(j), "");
}

TEST(JobSpec, UnknownNamesAreErrors) {
    json j = valid_spec();
    j["colour"] = "blue";
    EXPECT_TRUE(starts_with(error_of(j), "colour: unknown field")) << error_of(j);
    j = valid_spec();
    j["outputs"]["lightmap"]["resolution"] = 64;
    EXPECT_TRUE(starts_with(error_of(j), "lightmap.resolution: unknown setting")) << error_of(j);
    // A setting of another output is unknown here: the sh settings are not the lightmap's.
    j = valid_spec();
    j["outputs"]["lightmap"]["sh_bands"] = 2;
    EXPECT_EQ(field_of(j), "lightmap.sh_bands");
    // res moved to the atlas.
    j = valid_spec();
    j["outputs"]["lightmap"]["res"] = 256;
    EXPECT_EQ(field_of(j), "lightmap.res");
    j = valid_spec();
    j["atlas"]["padding"] = 2;
    EXPECT_TRUE(starts_with(error_of(j), "atlas.padding: unknown setting")) << error_of(j);
    j = valid_spec();
    j["outputs"]["radiance"] = json::object();
    EXPECT_TRUE(starts_with(error_of(j), "outputs.radiance: unknown output")) << error_of(j);
    j = valid_spec();
    j["limits"] = {{"gpu", 2}};
    EXPECT_TRUE(starts_with(error_of(j), "limits.gpu: unknown field")) << error_of(j);
}

TEST(JobSpec, WrongTypesAndRangesNameTheField) {
    auto with = [](const std::string& key, const json& v) {
        json j = valid_spec();
        j["outputs"]["lightmap"][key] = v;
        return error_of(j);
    };
    auto atlas_with = [](const std::string& key, const json& v) {
        json j = valid_spec();
        j["atlas"] = {{key, v}};
        return error_of(j);
    };
    EXPECT_EQ(atlas_with("res", 0), "atlas.res: 0 is below the minimum 1");
    EXPECT_EQ(atlas_with("res", 256.5), "atlas.res: must be an integer, not 256.5");
    EXPECT_TRUE(starts_with(atlas_with("res", "256"), "atlas.res: must be a number or \"auto\""))
        << atlas_with("res", "256");
    EXPECT_EQ(atlas_with("res", 100000), "atlas.res: 100000 exceeds the maximum 16384");
    EXPECT_EQ(atlas_with("res", 10000), "atlas.res: 10000 exceeds this server's limit 8192");
    EXPECT_EQ(atlas_with("texel_density", 0), "atlas.texel_density: 0 is below the minimum (exclusive) 0");
    EXPECT_EQ(atlas_with("subsamples", 9), "atlas.subsamples: 9 exceeds the maximum 8");
    EXPECT_EQ(with("passes", -3), "lightmap.passes: -3 is below the minimum 1");
    EXPECT_EQ(with("passes", "16"), "lightmap.passes: must be a number, not a string");
    EXPECT_EQ(with("passes", true), "lightmap.passes: must be a number, not a boolean");
    EXPECT_EQ(with("target_error", -0.5), "lightmap.target_error: -0.5 is below the minimum 0");
    EXPECT_EQ(with("target_error", 0), "") << "0: no target";
    EXPECT_EQ(with("time_limit", 1e9), "lightmap.time_limit: 1000000000 exceeds the maximum 10000000");
    EXPECT_EQ(with("time_limit", 20000), "lightmap.time_limit: 20000 exceeds this server's limit 14400");
    EXPECT_TRUE(
        starts_with(with("scheme", "fast"), "lightmap.scheme: must be one of epochs, final-gather, thesis, pathtrace"))
        << with("scheme", "fast");
    EXPECT_EQ(with("stitch", "no"), "lightmap.stitch: must be true or false, not a string");

    json j = valid_spec();
    j.erase("scene");
    EXPECT_EQ(error_of(j), "scene: is required");
    j = valid_spec();
    j["scene"] = 3;
    EXPECT_EQ(field_of(j), "scene");
    j = valid_spec();
    j.erase("outputs");
    EXPECT_EQ(error_of(j), "outputs: is required");
    j = valid_spec();
    j["outputs"] = json::object();
    EXPECT_TRUE(starts_with(error_of(j), "outputs: must ask for at least one output")) << error_of(j);
    j["outputs"] = json::array();
    EXPECT_EQ(field_of(j), "outputs");
    j = valid_spec();
    j["outputs"]["lightmap"] = 3;
    EXPECT_EQ(error_of(j), "outputs.lightmap: must be an object, not an integer");
    j = valid_spec();
    j["atlas"] = 3;
    EXPECT_EQ(error_of(j), "atlas: must be an object, not an integer");
    j = valid_spec();
    j["limits"] = {{"max_attempts", 100}};
    EXPECT_TRUE(starts_with(error_of(j), "limits.max_attempts: 100 exceeds this server's limit")) << error_of(j);
    j["limits"] = {{"max_attempts", 0}};
    EXPECT_EQ(field_of(j), "limits.max_attempts");
    j["limits"] = {{"max_seconds", 0}};
    EXPECT_EQ(field_of(j), "limits.max_seconds");
    j["limits"] = 5;
    EXPECT_EQ(field_of(j), "limits");
    EXPECT_EQ(field_of(json::array()), "(none)");
}

TEST(JobSpec, EnvironmentIsASkyOrAFileTheServiceRefuses) {
    json j = valid_spec();
    j["env"] = {0.5, 0.25, 1.0};
    const JobSpec spec = parse_job_spec(j);
    ASSERT_TRUE(spec.bake.env.sky);
    EXPECT_FLOAT_EQ((*spec.bake.env.sky)[1], 0.25f);
    j["env"] = {0.5, 0.25};
    EXPECT_EQ(field_of(j), "env");
    j["env"] = {0.5, -0.25, 1.0};
    EXPECT_EQ(field_of(j), "env");
    j["env"] = 3;
    EXPECT_EQ(field_of(j), "env");
    // A map file: for every output (the lightmap's and the probes' rays
    // see it as SH's do), and never on a server.
    json sh = sh_spec("sh_bands", 4);
    sh["env"] = "sky.hdr";
    EXPECT_EQ(parse_job_spec(sh).bake.env.map_file, "sky.hdr");
    SpecLimits server;
    server.allow_local_files = false;
    EXPECT_EQ(field_of(sh, server), "env");
    j["env"] = "sky.hdr";
    EXPECT_EQ(parse_job_spec(j).bake.env.map_file, "sky.hdr");
    EXPECT_EQ(field_of(j, server), "env");
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

TEST(JobSpec, ServerLimitsCapSettings) {
    SpecLimits small;
    small.caps["res"] = 512;
    small.caps["passes"] = 100;
    json j = valid_spec();
    j["atlas"]["res"] = 1024;
    EXPECT_EQ(error_of(j, small), "atlas.res: 1024 exceeds this server's limit 512");
    j["atlas"]["res"] = 512;
    EXPECT_EQ(error_of(j, small), "");
    // The "passes" limit caps every output's passes.
    EXPECT_EQ(field_of(sh_spec("sh_passes", 101), small), "sh.sh_passes");
    // No cap at all: the catalog's range alone.
    SpecLimits none;
    none.caps.clear();
    j["atlas"]["res"] = 16384;
    EXPECT_EQ(error_of(j, none), "");
}

// to_json(parse(x)) is canonical: parsing it again gives the same JSON.
TEST(JobSpec, CanonicalJsonIsAFixedPoint) {
    const std::vector<json> specs = {
        valid_spec(),
        {{"scene", "s"}, {"outputs", {{"sh", json::object()}}}},
        {{"scene", "s"},
         {"outputs",
          {{"lightmap", {{"scheme", "pathtrace"}, {"stitch", false}, {"target_error", 0.01}, {"time_limit", 30}}},
           {"sh", {{"sh_bands", 2}, {"sh_occluders", {0, 3}}, {"sh_per_texel", true}, {"sh_window", "lanczos"}}}}},
         {"atlas", {{"texel_density", 12.5}, {"subsamples", 3}}},
         {"env", {0.1, 0.2, 0.3}},
         {"seed", 4294967295ull},
         {"limits", {{"max_seconds", 60.5}, {"max_attempts", 2}}}},
    };
    for (const json& x : specs) {
        SCOPED_TRACE(x.dump());
        const json once = to_json(parse_job_spec(x));
        const json twice = to_json(parse_job_spec(once));
        EXPECT_EQ(once, twice);
        EXPECT_EQ(to_json(parse_bake_settings(x)), to_json(parse_bake_settings(to_json(parse_bake_settings(x)))));
        EXPECT_EQ(bake_identity(parse_job_spec(x)), bake_identity(parse_job_spec(once)));
    }
    const JobSpec limited = parse_job_spec(specs[2]);
    EXPECT_EQ(*limited.limits.max_attempts, 2);
    EXPECT_DOUBLE_EQ(*limited.limits.max_seconds, 60.5);
    EXPECT_EQ(limited.bake.output("sh")->values["sh_occluders"].get<std::vector<int>>(), (std::vector<int>{0, 3}));
}

TEST(JobSpec, BakeIdentityIgnoresLimitsAndKeyOrderButNotDefaults) {
    const json a = valid_spec();
    json b = json::parse(R"({"seed": 7, "atlas": {"res": 256}, "outputs": {"lightmap": {"passes": 16}}, "scene": "abc",
                             "limits": {"max_attempts": 1}})");
    EXPECT_EQ(bake_identity(parse_job_spec(a)), bake_identity(parse_job_spec(b)));
    // A default written out is the same bake as the default left out.
    b["outputs"]["lightmap"]["scheme"] = "epochs";
    EXPECT_EQ(bake_identity(parse_job_spec(a)), bake_identity(parse_job_spec(b)));
    b["seed"] = 8;
    EXPECT_NE(bake_identity(parse_job_spec(a)), bake_identity(parse_job_spec(b)));
}

// ---------------------------------------------------------------------------
// bake_json_from_flags: the CLI's flags through the same catalog

TEST(Flags, ErrorsNameTheFlag) {
    EXPECT_EQ(flag_error_of({{"--passes", "many"}}), "--passes: 'many' is not an integer");
    EXPECT_EQ(flag_error_of({{"--res", "0"}}), "--res: 0 is below the minimum 1");
    EXPECT_EQ(flag_error_of({{"--sh-bands", "0"}}), "--sh-bands: 0 is below the minimum 1");
    EXPECT_EQ(flag_error_of({{"--sh-bands", "9"}}), "--sh-bands: 9 exceeds the maximum 4");
    EXPECT_EQ(flag_error_of({{"--sh-bounces", "7"}}), "--sh-bounces: 7 exceeds the maximum 4");
    EXPECT_EQ(flag_error_of({{"--seed", "4294967296"}}), "--seed: 4294967296 exceeds the maximum 4294967295");
    EXPECT_EQ(flag_error_of({{"--seed", "4294967295"}}), "");
    EXPECT_TRUE(starts_with(flag_error_of({{"--scheme", "fast"}}), "--scheme: must be one of"))
        << flag_error_of({{"--scheme", "fast"}});
    EXPECT_TRUE(starts_with(flag_error_of({{"--texel-density", "dense"}}), "--texel-density: 'dense' is not a number"));
    EXPECT_TRUE(starts_with(flag_error_of({{"--sh-occluders", "0,,3"}}), "--sh-occluders:"));
    EXPECT_TRUE(starts_with(flag_error_of({{"--env", "1,2"}}), "--env:"));
    EXPECT_TRUE(starts_with(flag_error_of({{"--resolution", "256"}}), "--resolution: unknown bake option"));
    EXPECT_TRUE(starts_with(flag_error_of({{"--res", "256"}, {"--texel-density", "10"}}), "--texel-density:"));
    try {
        bake_json_from_flags({{"--passes", "many"}});
        FAIL();
    } catch (const SpecError& e) {
        EXPECT_EQ(e.field(), "--passes");
    }
}

TEST(Flags, ChooseOutputs) {
    // No output flag and no output setting: the lightmap.
    EXPECT_EQ(bake_json_from_flags({})["outputs"], json({{"lightmap", json::object()}}));
    EXPECT_EQ(bake_json_from_flags({{"--seed", "3"}})["outputs"], json({{"lightmap", json::object()}}));
    EXPECT_EQ(bake_json_from_flags({{"--res", "128"}})["outputs"], json({{"lightmap", json::object()}}));
    // An sh setting alone selects only the sh output.
    const json sh = bake_json_from_flags({{"--sh-bands", "2"}});
    EXPECT_EQ(sh["outputs"], json({{"sh", {{"sh_bands", 2}}}}));
    EXPECT_EQ(bake_json_from_flags({{"--sh", ""}})["outputs"], json({{"sh", json::object()}}));
    EXPECT_EQ(bake_json_from_flags({{"--sh", ""}, {"--lightmap", ""}})["outputs"],
              json({{"lightmap", json::object()}, {"sh", json::object()}}));
    EXPECT_EQ(bake_json_from_flags({{"--passes", "8"}, {"--sh", ""}})["outputs"],
              json({{"lightmap", {{"passes", 8}}}, {"sh", json::object()}}));
    const BakeSettings b = parse_bake_settings(sh);
    EXPECT_FALSE(b.output("lightmap"));
    ASSERT_TRUE(b.output("sh"));
    EXPECT_EQ(b.output("sh")->integer("sh_bands"), 2);
}

TEST(Flags, BecomeTheSameSettingsAsJson) {
    const json j = bake_json_from_flags({{"--res", "128"},
                                         {"--target-error", "0.02"},
                                         {"--no-stitch", ""},
                                         {"--sh-per-texel", ""},
                                         {"--sh-bands", "auto"},
                                         {"--sh-occluders", "0,3"},
                                         {"--env", "0.5,0.25,1"},
                                         {"--seed", "9"},
                                         {"--scheme", "thesis"}});
    const BakeSettings b = parse_bake_settings(j);
    ASSERT_TRUE(b.output("lightmap") && b.output("sh"));
    EXPECT_EQ(b.atlas.res, 128);
    EXPECT_DOUBLE_EQ(b.output("lightmap")->stop().target_error, 0.02);
    EXPECT_FALSE(b.output("lightmap")->flag("stitch"));
    EXPECT_EQ(b.output("lightmap")->choice("scheme"), "thesis");
    EXPECT_TRUE(b.output("sh")->flag("sh_per_texel"));
    EXPECT_FALSE(b.output("sh")->integer_or_auto("sh_bands"));
    EXPECT_EQ(b.output("sh")->values["sh_occluders"].get<std::vector<int>>(), (std::vector<int>{0, 3}));
    ASSERT_TRUE(b.env.sky);
    EXPECT_FLOAT_EQ((*b.env.sky)[1], 0.25f);
    EXPECT_EQ(b.seed, 9u);
    const BakeSettings same =
        parse_bake_settings({{"outputs",
                              {{"lightmap", {{"target_error", 0.02}, {"stitch", false}, {"scheme", "thesis"}}},
                               {"sh", {{"sh_per_texel", true}, {"sh_bands", "auto"}, {"sh_occluders", {0, 3}}}}}},
                             {"atlas", {{"res", 128}}},
                             {"env", {0.5, 0.25, 1}},
                             {"seed", 9}});
    EXPECT_EQ(to_json(b), to_json(same));
}

// atlas.mesh_scale: glTF mesh index -> its charts' texel density over the
// atlas's, as the file's extras say it, from a spec (JSON keys) or the CLI
// ("3=2,5=0.25"); each mistake names the field, a scale the key too.
TEST(JobSpec, AtlasMeshScaleMapsMeshesToScales) {
    json j = valid_spec();
    j["atlas"] = {{"mesh_scale", {{"3", 2}, {"0", 0.25}}}};
    const JobSpec spec = parse_job_spec(j);
    EXPECT_EQ(spec.bake.atlas.mesh_scale, (std::map<int, double>{{0, 0.25}, {3, 2.0}}));
    EXPECT_EQ(to_json(spec.bake)["atlas"]["mesh_scale"], json({{"0", 0.25}, {"3", 2}}));
    EXPECT_EQ(parse_job_spec(valid_spec()).bake.atlas.mesh_scale.size(), 0u);
    for (const auto& [value, field] :
         std::vector<std::pair<json, std::string>>{{json::array({3}), "atlas.mesh_scale"},
                                                   {json{{"x", 1}}, "atlas.mesh_scale"},
                                                   {json{{"-1", 1}}, "atlas.mesh_scale"},
                                                   {json{{"03", 1}}, "atlas.mesh_scale"},
                                                   {json{{"3", -0.5}}, "atlas.mesh_scale.3"},
                                                   {json{{"3", 64.5}}, "atlas.mesh_scale.3"},
                                                   {json{{"3", "2"}}, "atlas.mesh_scale.3"}}) {
        j["atlas"] = {{"mesh_scale", value}};
        EXPECT_EQ(field_of(j), field) << value.dump();
    }
    j["atlas"] = {{"mesh_scale", {{"3", 64}}}};
    EXPECT_EQ(field_of(j), "") << "64 is the largest scale, as for the file's extras";
    j["atlas"] = {{"mesh_scale", {{"3", 0}}}};
    EXPECT_EQ(field_of(j), "") << "0: no lightmap, as for the file's extras";

    const BakeSettings flags = parse_bake_settings(bake_json_from_flags({{"--mesh-scale", "3=2,5=0.25"}}));
    EXPECT_EQ(flags.atlas.mesh_scale, (std::map<int, double>{{3, 2.0}, {5, 0.25}}));
    for (const char* bad : {"3", "3=", "=2", "3=2,", "3=x", "a=2"})
        EXPECT_THROW(bake_json_from_flags({{"--mesh-scale", bad}}), SpecError) << bad;
    EXPECT_THROW(parse_bake_settings(bake_json_from_flags({{"--mesh-scale", "3=-1"}})), SpecError);
    EXPECT_THROW(parse_bake_settings(bake_json_from_flags({{"--mesh-scale", "3=65"}})), SpecError);
    EXPECT_EQ(parse_bake_settings(bake_json_from_flags({{"--mesh-scale", "3=0"}})).atlas.mesh_scale,
              (std::map<int, double>{{3, 0.0}}))
        << "0: no lightmap";
}

// The server checks a spec's mesh indices against the scene it names.
TEST(JobSpec, MeshIndicesTheSceneDoesNotDrawAreRefusedAtSubmit) {
    SceneSummary scene;
    scene.source = "room.glb";
    scene.emissive_triangles = 2;
    scene.details = {{"meshes", 4}};
    json j = valid_spec();
    j["atlas"] = {{"res", 256}, {"mesh_scale", {{"3", 2}}}};
    EXPECT_NO_THROW(check_spec_against_scene(parse_job_spec(j).bake, scene));
    j["atlas"]["mesh_scale"] = {{"4", 2}};
    try {
        check_spec_against_scene(parse_job_spec(j).bake, scene);
        ADD_FAILURE() << "mesh 4 of 4 accepted";
    } catch (const SpecError& e) {
        EXPECT_EQ(e.field(), "atlas.mesh_scale");
        EXPECT_NE(std::string(e.what()).find("mesh 4 is not drawn by room.glb (it has 4 meshes: 0 to 3)"),
                  std::string::npos)
            << e.what();
    }
}

TEST(Flags, OverrideABaseSpec) {
    const json base = {{"scene", "ignored"},
                       {"outputs", {{"lightmap", {{"passes", 64}, {"scheme", "thesis"}}}}},
                       {"atlas", {{"res", 512}}},
                       {"seed", 3}};
    const json j = bake_json_from_flags({{"--passes", "8"}, {"--res", "128"}, {"--seed", "5"}}, base);
    const BakeSettings b = parse_bake_settings(j);
    ASSERT_TRUE(b.output("lightmap"));
    EXPECT_FALSE(b.output("sh"));
    EXPECT_EQ(b.output("lightmap")->stop().passes, 8);
    EXPECT_EQ(b.output("lightmap")->choice("scheme"), "thesis") << "what no flag sets comes from the base";
    EXPECT_EQ(b.atlas.res, 128);
    EXPECT_EQ(b.seed, 5u);
    // Outputs named by flag are added to those of the base.
    const json both = bake_json_from_flags({{"--sh-bands", "2"}}, base);
    EXPECT_EQ(both["outputs"]["lightmap"], base["outputs"]["lightmap"]);
    EXPECT_EQ(both["outputs"]["sh"], json({{"sh_bands", 2}}));
    // A base's outputs stand without output flags: no lightmap is added to an sh spec.
    const json sh_base = {{"outputs", {{"sh", json::object()}}}};
    EXPECT_EQ(bake_json_from_flags({{"--seed", "2"}}, sh_base)["outputs"], sh_base["outputs"]);
    // A bad value in the base keeps its field name; a bad flag is named as the flag.
    json bad = base;
    bad["outputs"]["lightmap"]["passes"] = 0;
    EXPECT_EQ(flag_error_of({{"--seed", "2"}}, bad), "lightmap.passes: 0 is below the minimum 1");
    EXPECT_EQ(flag_error_of({{"--passes", "0"}}, base), "--passes: 0 is below the minimum 1");
    EXPECT_EQ(flag_error_of({{"--passes", "4"}}, bad), "") << "the flag replaces the bad value";
}

// ---------------------------------------------------------------------------
// check_spec_against_scene: what can be known at submit

TEST(SceneCheck, NoLightNoEnvironmentIsRefusedForTheLightmap) {
    SceneSummary dark;
    dark.source = "breakfast_room.gltf";
    dark.triangles = 1000;
    const BakeSettings lightmap = parse_bake_settings({{"outputs", {{"lightmap", json::object()}}}});
    try {
        check_spec_against_scene(lightmap, dark);
        FAIL() << "a dark scene was accepted";
    } catch (const SpecError& e) {
        EXPECT_EQ(e.field(), "env");
        const std::string what = e.what();
        EXPECT_NE(what.find("breakfast_room.gltf"), std::string::npos) << what;
        EXPECT_NE(what.find("--env"), std::string::npos) << what;
    }
    // With a sky it bakes; with a light it bakes; an SH transfer needs no light.
    EXPECT_NO_THROW(check_spec_against_scene(
        parse_bake_settings({{"outputs", {{"lightmap", json::object()}}}, {"env", {1, 1, 1}}}), dark));
    EXPECT_NO_THROW(check_spec_against_scene(parse_bake_settings({{"outputs", {{"sh", json::object()}}}}), dark));
    SceneSummary lit = dark;
    lit.emissive_triangles = 2;
    EXPECT_NO_THROW(check_spec_against_scene(lightmap, lit));
    lit = dark;
    lit.punctual_lights = 1;
    EXPECT_NO_THROW(check_spec_against_scene(lightmap, lit));
}

TEST(SceneCheck, AnAtlasThatCannotFitNamesTheSmallestRes) {
    SceneSummary stairs;
    stairs.source = "staircase.glb";
    stairs.emissive_triangles = 4;
    stairs.min_atlas_res = 1536;
    auto with_res = [](const json& res, const json& outputs) {
        return parse_bake_settings({{"outputs", outputs}, {"atlas", {{"res", res}}}});
    };
    const json lightmap = {{"lightmap", json::object()}};
    try {
        check_spec_against_scene(with_res(256, lightmap), stairs);
        FAIL() << "an atlas of 256 was accepted for a scene that needs 1536";
    } catch (const SpecError& e) {
        EXPECT_EQ(e.field(), "atlas.res");
        const std::string what = e.what();
        EXPECT_NE(what.find("1536"), std::string::npos) << what;
        EXPECT_NE(what.find("staircase.glb"), std::string::npos) << what;
    }
    EXPECT_NO_THROW(check_spec_against_scene(with_res(1536, lightmap), stairs));
    EXPECT_NO_THROW(check_spec_against_scene(with_res("auto", lightmap), stairs));
    // Per-vertex SH uses no atlas; per-texel SH does.
    EXPECT_NO_THROW(check_spec_against_scene(with_res(256, {{"sh", json::object()}}), stairs));
    EXPECT_THROW(check_spec_against_scene(with_res(256, {{"sh", {{"sh_per_texel", true}}}}), stairs), SpecError);
    // The file's own TEXCOORD_1 is the atlas at any res.
    SceneSummary uvs = stairs;
    uvs.has_lightmap_uvs = true;
    EXPECT_NO_THROW(check_spec_against_scene(with_res(256, lightmap), uvs));
    // Unknown (0): nothing to check.
    SceneSummary unknown = stairs;
    unknown.min_atlas_res = 0;
    EXPECT_NO_THROW(check_spec_against_scene(with_res(16, lightmap), unknown));
}

// ---------------------------------------------------------------------------
// The engine-server contract

Progress some_progress() {
    Progress p;
    p.pass = 12;
    p.rays = (uint64_t(1) << 40) + 3;
    p.seconds = 3.25;
    p.error_estimate = 0.0125;
    return p;
}

void expect_same(const Progress& a, const Progress& b) {
    EXPECT_EQ(a.pass, b.pass);
    EXPECT_EQ(a.rays, b.rays);
    EXPECT_DOUBLE_EQ(a.seconds, b.seconds);
    EXPECT_EQ(a.error_estimate, b.error_estimate);
}

// Through text, as a worker's stdout line travels.
WorkerEvent through_a_line(const WorkerEvent& e) { return parse_worker_event(json::parse(to_json(e).dump())); }

TEST(WorkerEvents, RoundTripEachType) {
    StartEvent start;
    start.vendor = "NVIDIA Corporation";
    start.renderer = "NVIDIA H100 80GB HBM3/PCIe/SSE2";
    start.triangles = 123456;
    start.prepare_seconds = 0.75;
    start.outputs = {{"lightmap", {{"texels", 65536}}}, {"sh", {{"vertices", 100}}}};
    start.resumed["lightmap"] = some_progress();
    start.not_resumed["sh"] = "no state was saved";
    start.warnings = {"texel density 5000 texels/m does not fit in a 256² atlas (max_res): baked at 53.69 texels/m"};
    const WorkerEvent s = through_a_line(start);
    ASSERT_TRUE(std::holds_alternative<StartEvent>(s));
    const auto& s2 = std::get<StartEvent>(s);
    EXPECT_EQ(s2.vendor, start.vendor);
    EXPECT_EQ(s2.renderer, start.renderer);
    EXPECT_EQ(s2.triangles, start.triangles);
    EXPECT_DOUBLE_EQ(s2.prepare_seconds, start.prepare_seconds);
    EXPECT_EQ(s2.outputs, start.outputs);
    ASSERT_EQ(s2.resumed.size(), 1u);
    expect_same(s2.resumed.at("lightmap"), start.resumed.at("lightmap"));
    EXPECT_EQ(s2.not_resumed, start.not_resumed);
    EXPECT_EQ(s2.warnings, start.warnings);
    EXPECT_FALSE(to_json(WorkerEvent(StartEvent{})).contains("warnings")) << "none to say: no key";
    EXPECT_EQ(to_json(s)["event"], "start");
    EXPECT_FALSE(to_json(WorkerEvent(StartEvent{})).contains("resumed")) << "a fresh bake says nothing of resuming";

    ProgressEvent progress{"sh", some_progress()};
    progress.progress.eta_seconds = 9.0;  // the server's business: not on the worker's line
    EXPECT_FALSE(to_json(WorkerEvent(progress)).contains("eta_seconds"));
    const WorkerEvent p = through_a_line(progress);
    ASSERT_TRUE(std::holds_alternative<ProgressEvent>(p));
    EXPECT_EQ(std::get<ProgressEvent>(p).output, "sh");
    expect_same(std::get<ProgressEvent>(p).progress, progress.progress);
    EXPECT_FALSE(std::get<ProgressEvent>(p).progress.eta_seconds);
    ProgressEvent early{"lightmap", Progress{}};  // no error estimate yet
    const WorkerEvent e = through_a_line(early);
    EXPECT_FALSE(std::get<ProgressEvent>(e).progress.error_estimate);

    const SnapshotEvent snapshot{"lightmap", "lightmap.pass-16384.exr", 16384};
    const WorkerEvent n = through_a_line(snapshot);
    ASSERT_TRUE(std::holds_alternative<SnapshotEvent>(n));
    EXPECT_EQ(std::get<SnapshotEvent>(n).output, "lightmap");
    EXPECT_EQ(std::get<SnapshotEvent>(n).file, "lightmap.pass-16384.exr");
    EXPECT_EQ(std::get<SnapshotEvent>(n).pass, 16384);

    DoneEvent done;
    done.progress = some_progress();
    done.files = {"lightmap.exr", "lightmap.pass-0001.exr", "scene.sh.glb", "manifest.json"};
    done.final_files = {{"lightmap", "lightmap.exr"}, {"sh", "scene.sh.glb"}};
    const WorkerEvent d = through_a_line(done);
    ASSERT_TRUE(std::holds_alternative<DoneEvent>(d));
    expect_same(std::get<DoneEvent>(d).progress, done.progress);
    EXPECT_EQ(std::get<DoneEvent>(d).files, done.files);
    EXPECT_EQ(std::get<DoneEvent>(d).final_files, done.final_files);

    const PrepareEvent prepare{"texel_samples", 2.5, 7.25};
    const WorkerEvent r = through_a_line(prepare);
    ASSERT_TRUE(std::holds_alternative<PrepareEvent>(r));
    EXPECT_EQ(std::get<PrepareEvent>(r).stage, "texel_samples");
    EXPECT_DOUBLE_EQ(std::get<PrepareEvent>(r).seconds, 2.5);
    EXPECT_EQ(std::get<PrepareEvent>(r).eta_seconds, 7.25);
    EXPECT_FALSE(std::get<PrepareEvent>(through_a_line(PrepareEvent{"load", 0.0, {}})).eta_seconds);
    EXPECT_THROW(parse_worker_event({{"event", "prepare"}}), std::invalid_argument) << "a stage is named";

    // Every event's JSON is a fixed point.
    for (const WorkerEvent& ev :
         {WorkerEvent(prepare), WorkerEvent(start), WorkerEvent(progress), WorkerEvent(snapshot), WorkerEvent(done)})
        EXPECT_EQ(to_json(through_a_line(ev)), to_json(ev));
}

TEST(WorkerEvents, GarbageIsRefused) {
    const std::vector<json> garbage = {
        json(nullptr),
        json("progress"),
        json::array({"event", "done"}),
        json::object(),
        {{"event", 3}},
        {{"event", "finished"}},
        {{"event", "snapshot"}, {"output", "lightmap"}, {"pass", 4}},               // no file
        {{"event", "snapshot"}, {"output", "lightmap"}, {"file", "a.exr"}},         // no pass
        {{"event", "snapshot"}, {"output", "lightmap"}, {"file", 7}, {"pass", 4}},  // file not a string
        {{"event", "snapshot"}, {"output", "lightmap"}, {"file", "a.exr"}, {"pass", "4"}},
    };
    for (const json& g : garbage) EXPECT_THROW(parse_worker_event(g), std::invalid_argument) << g.dump();
}

// A field of the wrong type is refused too. (The header promises
// std::invalid_argument; today some of these throw nlohmann's type_error,
// which the supervisor's catch of std::exception also takes.)
TEST(WorkerEvents, WrongFieldTypesAreRefused) {
    const std::vector<json> garbage = {
        {{"event", "progress"}, {"output", 3}, {"pass", 1}},
        {{"event", "start"}, {"vendor", 5}},
        {{"event", "snapshot"}, {"output", json::array()}, {"file", "a.exr"}, {"pass", 4}},
    };
    for (const json& g : garbage) EXPECT_ANY_THROW(parse_worker_event(g)) << g.dump();
}

TEST(WorkerExit, InputErrorsAreNotRetried) {
    EXPECT_TRUE(is_input_error_exit(kExitUsage));
    EXPECT_TRUE(is_input_error_exit(kExitInputError));
    EXPECT_FALSE(is_input_error_exit(kExitOk));
    EXPECT_FALSE(is_input_error_exit(kExitFailure));
    EXPECT_FALSE(is_input_error_exit(137));  // SIGKILL
    EXPECT_FALSE(is_input_error_exit(-1));
}

TEST(SceneSummaryJson, RoundTrips) {
    SceneSummary s;
    s.source = "breakfast_room.gltf";
    s.triangles = 269000;
    s.emissive_triangles = 0;
    s.punctual_lights = 3;
    s.max_texture_size = 2048;
    s.has_lightmap_uvs = false;
    s.min_atlas_res = 1536;
    s.details = {{"meshes", 12}, {"warnings", {"no TEXCOORD_1"}}};
    const json j = to_json(s);
    EXPECT_EQ(j["meshes"], 12) << "the engine's other fields are kept";
    EXPECT_EQ(j["punctual_light_count"], 3);
    const SceneSummary t = scene_summary_from_json(json::parse(j.dump()));
    EXPECT_EQ(t.source, s.source);
    EXPECT_EQ(t.triangles, s.triangles);
    EXPECT_EQ(t.emissive_triangles, s.emissive_triangles);
    EXPECT_EQ(t.punctual_lights, s.punctual_lights);
    EXPECT_EQ(t.max_texture_size, s.max_texture_size);
    EXPECT_EQ(t.has_lightmap_uvs, s.has_lightmap_uvs);
    EXPECT_EQ(t.min_atlas_res, s.min_atlas_res);
    EXPECT_TRUE(t.has_light());
    EXPECT_EQ(to_json(t), j);
    EXPECT_THROW(scene_summary_from_json(json::array()), std::invalid_argument);
    // A summary from before min_atlas_res existed: unknown, not an error.
    const SceneSummary old = scene_summary_from_json(json::parse(R"({"triangles": 12, "emissive_triangles": 2})"));
    EXPECT_EQ(old.min_atlas_res, 0);
    EXPECT_TRUE(old.has_light());
}

TEST(ProgressJson, RoundTrips) {
    Progress p = some_progress();
    p.eta_seconds = 4.5;
    const Progress q = progress_from_json(json::parse(to_json(p).dump()));
    expect_same(p, q);
    EXPECT_EQ(q.eta_seconds, p.eta_seconds);
    EXPECT_EQ(to_json(Progress{})["error_estimate"], nullptr);
    EXPECT_EQ(progress_from_json(json("junk")).pass, 0);
}

// ---------------------------------------------------------------------------
// Job status and events

TEST(JobStatus, RoundTripsThroughJson) {
    JobStatus s;
    s.id = "j1";
    s.scene = "abc";
    s.state = JobState::Failed;
    s.spec = to_json(parse_job_spec(valid_spec()));
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
    EXPECT_FALSE(to_json(s).contains("queue")) << "only a queued job says where it stands";
    s.state = JobState::Queued;
    s.queue = QueuePlace{2, 1, std::nullopt};
    EXPECT_EQ(to_json(s)["queue"], json({{"ahead", 2}, {"running", 1}, {"starts_in_seconds", nullptr}}));
    EXPECT_EQ(to_json(status_from_json(to_json(s))), to_json(s));
    s.queue->starts_in_seconds = 42.5;
    EXPECT_EQ(to_json(s)["queue"]["starts_in_seconds"], 42.5);
    EXPECT_EQ(to_json(status_from_json(to_json(s))), to_json(s));
    EXPECT_TRUE(is_final(JobState::Cancelled));
    EXPECT_TRUE(is_final(JobState::Succeeded));
    EXPECT_TRUE(is_final(JobState::Failed));
    EXPECT_FALSE(is_final(JobState::Running));
    EXPECT_FALSE(is_final(JobState::Queued));
    EXPECT_EQ(parse_job_state("running"), JobState::Running);
    EXPECT_FALSE(parse_job_state("paused"));
}

TEST(JobStatus, EtaFollowsTheStoppingRules) {
    Progress p;
    StopSettings stop;
    stop.passes = 10;
    EXPECT_FALSE(estimate_eta(stop, p)) << "nothing to go on before the first pass";
    p.pass = 4;
    p.seconds = 2.0;  // 0.5 s per pass
    EXPECT_DOUBLE_EQ(*estimate_eta(stop, p), 3.0);
    stop.time_limit = 3;  // 1 s left, before the passes run out
    EXPECT_DOUBLE_EQ(*estimate_eta(stop, p), 1.0);
    stop = StopSettings{};
    stop.passes = 1000;
    stop.target_error = 0.01;
    p.error_estimate = 0.02;  // twice the target: 4x the passes, 12 more
    EXPECT_DOUBLE_EQ(*estimate_eta(stop, p), 6.0);
    p.error_estimate = 0.005;  // already there
    EXPECT_DOUBLE_EQ(*estimate_eta(stop, p), 0.0);
    // Past the end: never negative.
    stop = StopSettings{};
    stop.passes = 2;
    EXPECT_DOUBLE_EQ(*estimate_eta(stop, p), 0.0);
    // The catalog's default stop rules give an answer (256 passes).
    const BakeSettings b = parse_bake_settings({{"outputs", {{"lightmap", json::object()}}}});
    p.error_estimate.reset();
    EXPECT_DOUBLE_EQ(*estimate_eta(b.output("lightmap")->stop(), p), 0.5 * (256 - 4));
}

// One ETA for the whole job: a lightmap + SH job (baked in that order)
// counts the SH passes to come while its lightmap bakes, priced at the rate
// the job traces now and the start event's rays per pass.
TEST(JobStatus, OneEtaAcrossTheJobsOutputs) {
    const BakeSettings bake =
        parse_bake_settings({{"outputs", {{"lightmap", {{"passes", 10}}}, {"sh", {{"sh_passes", 20}}}}}});
    StartEvent start;
    start.prepare_seconds = 3.0;
    start.outputs = {{"lightmap", {{"rays_per_pass", 1000}}}, {"sh", {{"rays_per_pass", 500}}}};
    JobProgress job(bake);
    job.start(start);

    Progress lightmap;
    lightmap.pass = 4, lightmap.seconds = 2.0, lightmap.rays = 4000;  // 0.5 s a pass, 2000 rays/s
    Progress shown = job.update("lightmap", lightmap);
    // 6 lightmap passes at 0.5 s, then 20 SH passes of 500 rays at 2000 rays/s.
    EXPECT_DOUBLE_EQ(*shown.eta_seconds, 3.0 + 20 * 0.25);
    EXPECT_DOUBLE_EQ(shown.prepare_seconds, 3.0);
    EXPECT_DOUBLE_EQ(shown.earlier_outputs_seconds, 0.0);
    EXPECT_DOUBLE_EQ(*done_fraction(shown), 5.0 / (5.0 + 8.0));

    lightmap.pass = 10, lightmap.seconds = 5.0, lightmap.rays = 10000;
    shown = job.update("lightmap", lightmap);
    EXPECT_DOUBLE_EQ(*shown.eta_seconds, 5.0) << "the lightmap's end is not the job's";

    Progress sh;
    sh.pass = 5, sh.seconds = 1.0, sh.rays = 2500;
    shown = job.update("sh", sh);
    EXPECT_DOUBLE_EQ(*shown.eta_seconds, 3.0);  // 15 passes at 0.2 s: nothing after SH
    EXPECT_DOUBLE_EQ(shown.earlier_outputs_seconds, 5.0);
    EXPECT_DOUBLE_EQ(*done_fraction(shown), (3.0 + 5.0 + 1.0) / (9.0 + 3.0));
}

// The whole job's bar never goes back (issue #54: a lightmap + SH job's
// went from 85% to 11% when SH started): SH's passes, priced at the
// lightmap's rate before it runs, prove ten times slower; the bar holds
// where it stood until the job catches up with it, and ends at 1. Through
// JSON too (the status and the events carry it).
TEST(JobStatus, TheWholeJobsBarNeverGoesBack) {
    const BakeSettings bake =
        parse_bake_settings({{"outputs", {{"lightmap", {{"passes", 10}}}, {"sh", {{"sh_passes", 20}}}}}});
    StartEvent start;
    start.outputs = {{"lightmap", {{"rays_per_pass", 1000}}}, {"sh", {{"rays_per_pass", 500}}}};
    JobProgress job(bake);
    job.start(start);
    double last = 0.0;
    std::vector<double> shown;
    const auto step = [&](const std::string& output, int pass, double seconds, uint64_t rays) {
        Progress p;
        p.pass = pass, p.seconds = seconds, p.rays = rays;
        const Progress out = progress_from_json(to_json(job.update(output, p)));
        const double fraction = *done_fraction(out);
        EXPECT_GE(fraction, last) << output << " pass " << pass;
        last = fraction;
        shown.push_back(fraction);
    };
    for (int pass = 1; pass <= 10; ++pass) step("lightmap", pass, 0.5 * pass, 1000u * pass);  // 2000 rays/s
    const double before_sh = last;
    for (int pass = 1; pass <= 20; ++pass) step("sh", pass, 2.5 * pass, 500u * pass);  // 200 rays/s
    EXPECT_DOUBLE_EQ(before_sh, 0.5);  // 5 s of lightmap, SH priced at 20 x 0.25 s
    EXPECT_DOUBLE_EQ(shown.back(), 1.0);
    // What the estimate alone said when SH began: far less than was shown.
    Progress first_sh;
    first_sh.pass = 1, first_sh.seconds = 2.5, first_sh.rays = 500;
    JobProgress fresh(bake);
    fresh.start(start);
    for (int pass = 1; pass <= 10; ++pass) {
        Progress p;
        p.pass = pass, p.seconds = 0.5 * pass, p.rays = 1000u * pass;
        fresh.update("lightmap", p);
    }
    Progress estimate_only = fresh.update("sh", first_sh);
    estimate_only.shown_fraction = 0.0;
    EXPECT_LT(*done_fraction(estimate_only), 0.5 * before_sh);
}

// An output to come is priced from where it resumes, never past its time
// limit, and not at all without its rays per pass (unknown, not a guess).
TEST(JobStatus, JobEtaOfOutputsToComeFollowsTheirStopRulesAndResumption) {
    const BakeSettings bake = parse_bake_settings(
        {{"outputs", {{"lightmap", {{"passes", 10}}}, {"sh", {{"sh_passes", 100}, {"sh_time_limit", 4}}}}}});
    Progress lightmap;
    lightmap.pass = 10, lightmap.seconds = 5.0, lightmap.rays = 10000;  // done: 2000 rays/s
    StartEvent start;
    start.outputs = {{"lightmap", {{"rays_per_pass", 1000}}}, {"sh", {{"rays_per_pass", 500}}}};
    {
        JobProgress job(bake);
        job.start(start);
        EXPECT_DOUBLE_EQ(*job.update("lightmap", lightmap).eta_seconds, 4.0) << "100 x 0.25 s, cut at 4 s";
    }
    {
        StartEvent resumed = start;
        resumed.resumed["sh"].pass = 90;
        resumed.resumed["sh"].seconds = 1.0;
        JobProgress job(bake);
        job.start(resumed);
        EXPECT_DOUBLE_EQ(*job.update("lightmap", lightmap).eta_seconds, 10 * 0.25);
    }
    {
        StartEvent unknown = start;
        unknown.outputs["sh"].erase("rays_per_pass");
        JobProgress job(bake);
        job.start(unknown);
        EXPECT_FALSE(job.update("lightmap", lightmap).eta_seconds);
    }
    // One output: the job's ETA is the output's own.
    const BakeSettings one = parse_bake_settings({{"outputs", {{"lightmap", {{"passes", 10}}}}}});
    JobProgress job(one);
    job.start(start);
    lightmap.pass = 4, lightmap.seconds = 2.0;
    EXPECT_DOUBLE_EQ(*job.update("lightmap", lightmap).eta_seconds,
                     *estimate_eta(one.output("lightmap")->stop(), lightmap));
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
    EXPECT_TRUE(is_final_event("failed"));
    EXPECT_TRUE(is_final_event("cancelled"));
    EXPECT_FALSE(is_final_event("snapshot"));
}

// ---------------------------------------------------------------------------
// protocol/openapi.json: the JobSpec schema is the catalog

std::filesystem::path openapi_path() {
#ifdef LIGHTFARM_OPENAPI
    return LIGHTFARM_OPENAPI;
#else
    return repo_root() / "protocol" / "openapi.json";
#endif
}

json load_openapi() {
    std::ifstream in(openapi_path());
    if (!in) throw std::runtime_error("cannot read " + openapi_path().string());
    return json::parse(in);
}

// "#/components/schemas/X" -> the schema; anything else as it is.
const json& resolve(const json& doc, const json& schema) {
    if (!schema.is_object() || !schema.contains("$ref")) return schema;
    const std::string ref = schema["$ref"];
    const std::string prefix = "#/components/schemas/";
    if (!starts_with(ref, prefix)) throw std::runtime_error("unsupported $ref " + ref);
    return resolve(doc, doc.at("components").at("schemas").at(ref.substr(prefix.size())));
}

// The JSON Schema of one setting, as the catalog defines it: what the
// OpenAPI document must say, word for word. The environment is the service's
// (a sky [R, G, B]: a server reads no map files).
json schema_of(const Setting& s) {
    json range = json::object();
    switch (s.type) {
    case SettingType::Integer:
    case SettingType::Number:
        range["type"] = s.type == SettingType::Integer ? "integer" : "number";
        range[s.min_exclusive ? "exclusiveMinimum" : "minimum"] = s.min;
        range["maximum"] = s.max;
        break;
    case SettingType::Choice: range = {{"type", "string"}, {"enum", s.choices}}; break;
    case SettingType::Flag: range = {{"type", "boolean"}}; break;
    case SettingType::MeshScales:
        range = {{"type", "object"},
                 {"propertyNames", {{"pattern", "^(0|[1-9][0-9]{0,8})$"}}},
                 {"additionalProperties", {{"type", "number"}, {"minimum", 0}, {"maximum", kMaxLightmapScale}}},
                 {"maxProperties", kMaxMeshList}};
        break;
    case SettingType::MeshList:
        range = {{"type", "array"},
                 {"items", {{"type", "integer"}, {"minimum", 0}, {"maximum", 1 << 30}}},
                 {"maxItems", kMaxMeshList}};
        break;
    case SettingType::Environment:
        range = {{"type", "array"}, {"items", {{"type", "number"}, {"minimum", 0}}}, {"minItems", 3}, {"maxItems", 3}};
        break;
    case SettingType::Positions: {
        const double f = std::numeric_limits<float>::max();
        const json coordinate = {{"type", "number"}, {"minimum", -f}, {"maximum", f}};
        const json point = {
            {"type", "object"},
            {"required", {"position"}},
            {"additionalProperties", false},
            {"properties",
             {{"position", {{"type", "array"}, {"items", coordinate}, {"minItems", 3}, {"maxItems", 3}}}}}};
        range = {{"type", "array"}, {"items", point}, {"maxItems", 4096}};
        break;
    }
    }
    json out = s.accepts_auto ? json{{"oneOf", {range, {{"const", "auto"}}}}} : range;
    if (!s.default_value.is_null()) out["default"] = s.default_value;
    out["description"] = s.help;
    if (!s.limit.empty()) out["x-server-limit"] = s.limit;
    return out;
}

// Numbers compare by value (1000 == 1000.0), everything else exactly.
bool same_schema(const json& a, const json& b) {
    if (a.is_number() && b.is_number()) return a.get<double>() == b.get<double>();
    if (a.type() != b.type()) return false;
    if (a.is_object()) {
        if (a.size() != b.size()) return false;
        for (auto it = a.begin(); it != a.end(); ++it)
            if (!b.contains(it.key()) || !same_schema(it.value(), b[it.key()])) return false;
        return true;
    }
    if (a.is_array()) {
        if (a.size() != b.size()) return false;
        for (size_t i = 0; i < a.size(); ++i)
            if (!same_schema(a[i], b[i])) return false;
        return true;
    }
    return a == b;
}

std::set<std::string> keys_of(const json& properties) {
    std::set<std::string> keys;
    for (auto it = properties.begin(); it != properties.end(); ++it) keys.insert(it.key());
    return keys;
}

// The object schema that holds a group's settings.
const json& group_schema(const json& doc, const std::string& group) {
    const json& spec = resolve(doc, doc["components"]["schemas"]["JobSpec"]);
    if (group.empty()) return spec;
    if (group == "atlas") return resolve(doc, spec["properties"]["atlas"]);
    return resolve(doc, spec["properties"]["outputs"]["properties"][group]);
}

TEST(OpenApi, JobSpecSchemaIsTheCatalog) {
    const json doc = load_openapi();
    const json& spec = resolve(doc, doc["components"]["schemas"]["JobSpec"]);
    EXPECT_EQ(spec["type"], "object");
    EXPECT_EQ(spec["additionalProperties"], false);
    EXPECT_EQ(spec["required"], json({"scene", "outputs"}));

    // The outputs: exactly output_names(), each an object of its settings.
    const json& outputs = spec["properties"]["outputs"];
    EXPECT_EQ(outputs["additionalProperties"], false);
    EXPECT_EQ(outputs["minProperties"], 1);
    EXPECT_EQ(keys_of(outputs["properties"]), std::set<std::string>(output_names().begin(), output_names().end()));

    // Every group: the same names, and every setting exactly as the catalog says.
    std::set<std::string> groups = {"", "atlas"};
    groups.insert(output_names().begin(), output_names().end());
    for (const std::string& group : groups) {
        SCOPED_TRACE("group '" + group + "'");
        const json& object = group_schema(doc, group);
        ASSERT_TRUE(object.is_object());
        EXPECT_EQ(object["type"], "object");
        EXPECT_EQ(object["additionalProperties"], false);
        std::set<std::string> in_catalog;
        for (const Setting& s : setting_catalog())
            if (s.group == group) in_catalog.insert(s.name);
        std::set<std::string> in_schema = keys_of(object["properties"]);
        if (group.empty()) {
            for (const char* own : {"scene", "outputs", "atlas", "limits"}) EXPECT_EQ(in_schema.erase(own), 1u) << own;
        }
        EXPECT_EQ(in_schema, in_catalog);
        for (const Setting& s : setting_catalog()) {
            if (s.group != group || !object["properties"].contains(s.name)) continue;
            const json& documented = object["properties"][s.name];
            EXPECT_TRUE(same_schema(documented, schema_of(s))) << s.field() << " is documented as\n"
                                                               << documented.dump(2) << "\nbut the catalog says\n"
                                                               << schema_of(s).dump(2);
        }
    }

    // The job's own limits.
    const json& limits = spec["properties"]["limits"];
    EXPECT_EQ(limits["additionalProperties"], false);
    EXPECT_EQ(keys_of(limits["properties"]), (std::set<std::string>{"max_attempts", "max_seconds"}));
    EXPECT_EQ(limits["properties"]["max_seconds"]["type"], "number");
    EXPECT_EQ(limits["properties"]["max_attempts"]["type"], "integer");
    EXPECT_EQ(spec["properties"]["scene"]["type"], "string");
}

// A small JSON Schema validator, for the subset openapi.json uses.
bool valid_against(const json& doc, const json& schema_ref, const json& v) {
    const json& schema = resolve(doc, schema_ref);
    if (schema.contains("oneOf")) {
        int matches = 0;
        for (const json& alt : schema["oneOf"]) matches += valid_against(doc, alt, v);
        if (matches != 1) return false;
    }
    if (schema.contains("const") && v != schema["const"]) return false;
    if (schema.contains("enum") && std::find(schema["enum"].begin(), schema["enum"].end(), v) == schema["enum"].end())
        return false;
    if (schema.contains("type")) {
        const std::string t = schema["type"];
        const bool ok = t == "integer"   ? (v.is_number_integer() || v.is_number_unsigned())
                        : t == "number"  ? v.is_number()
                        : t == "string"  ? v.is_string()
                        : t == "boolean" ? v.is_boolean()
                        : t == "array"   ? v.is_array()
                        : t == "object"  ? v.is_object()
                                         : false;
        if (!ok) return false;
    }
    if (v.is_number()) {
        const double x = v.get<double>();
        if (!std::isfinite(x)) return false;
        if (schema.contains("minimum") && x < schema["minimum"].get<double>()) return false;
        if (schema.contains("exclusiveMinimum") && x <= schema["exclusiveMinimum"].get<double>()) return false;
        if (schema.contains("maximum") && x > schema["maximum"].get<double>()) return false;
    }
    if (v.is_string() && schema.contains("minLength") &&
        v.get<std::string>().size() < schema["minLength"].get<size_t>())
        return false;
    if (v.is_array()) {
        if (schema.contains("minItems") && v.size() < schema["minItems"].get<size_t>()) return false;
        if (schema.contains("maxItems") && v.size() > schema["maxItems"].get<size_t>()) return false;
        if (schema.contains("items"))
            for (const json& item : v)
                if (!valid_against(doc, schema["items"], item)) return false;
    }
    if (v.is_object()) {
        if (schema.contains("minProperties") && v.size() < schema["minProperties"].get<size_t>()) return false;
        if (schema.contains("maxProperties") && v.size() > schema["maxProperties"].get<size_t>()) return false;
        if (schema.contains("propertyNames"))
            for (auto it = v.begin(); it != v.end(); ++it)
                if (!std::regex_search(it.key(), std::regex(schema["propertyNames"]["pattern"].get<std::string>())))
                    return false;
        if (schema.contains("required"))
            for (const json& r : schema["required"])
                if (!v.contains(r.get<std::string>())) return false;
        const json props = schema.value("properties", json::object());
        for (auto it = v.begin(); it != v.end(); ++it) {
            if (props.contains(it.key())) {
                if (!valid_against(doc, props[it.key()], it.value())) return false;
            } else if (schema.value("additionalProperties", json(true)) == false) {
                return false;
            } else if (schema.contains("additionalProperties") && schema["additionalProperties"].is_object() &&
                       !valid_against(doc, schema["additionalProperties"], it.value())) {
                return false;
            }
        }
    }
    return true;
}

// A value is valid in the OpenAPI document exactly when the server's parser
// takes it: every setting at and past its edges, of every wrong type.
TEST(OpenApi, SchemaAcceptsExactlyWhatTheServerAccepts) {
    const json doc = load_openapi();
    const json& schema = doc["components"]["schemas"]["JobSpec"];
    SpecLimits server;  // the catalog's ranges; the server's own caps are its configuration
    server.caps.clear();
    server.allow_local_files = false;
    auto accepted = [&](const json& spec) { return error_of(spec, server).empty(); };

    json base = {{"scene", "s"}, {"outputs", json::object()}};
    for (const std::string& o : output_names()) base["outputs"][o] = json::object();
    int checked = 0;
    for (const Setting& s : setting_catalog()) {
        std::vector<json> values = {nullptr, true, "auto", "x", json::array(), json::object(), 1.5, -1, 0, 1, 3};
        if (s.type == SettingType::Integer || s.type == SettingType::Number) {
            for (double d : {s.min - 1, s.min - 0.5, s.min, s.min + 0.5, s.max - 0.5, s.max, s.max + 0.5, s.max + 1}) {
                values.push_back(d);
                if (d == std::floor(d) && std::abs(d) < 9e15) values.push_back(int64_t(d));
            }
        }
        for (const std::string& c : s.choices) values.push_back(c);
        for (const json& v : {json::array({0, 3}), json::array({-1}), json::array({1.5}), json::array({1, 2, 3}),
                              json::array({0.5, 0.5}), json::array({-1, 0, 0}), json("0,3"), json("sky.hdr")})
            values.push_back(v);
        for (const json& v : {json{{"3", 2}}, json{{"0", 64}, {"12", 0.25}}, json{{"3", 0}}, json{{"3", 64.5}},
                              json{{"3", -1}}, json{{"3", "2"}}, json{{"03", 1}}, json{{"-1", 1}}, json{{"x", 1}},
                              json{{"1234567890", 1}}, json{{"", 1}}})
            values.push_back(v);
        for (const json& v : values) {
            json spec = base;
            if (s.group.empty()) spec[s.name] = v;
            else if (s.group == "atlas") spec["atlas"][s.name] = v;
            else spec["outputs"][s.group][s.name] = v;
            // "M divides R" is a rule between two settings, which the schema
            // states in words: R = M where M is a valid R, else R = 48, which
            // every other M tried here divides.
            if (s.name == "probe_m") {
                const bool an_r = v.is_number_integer() && v.get<int64_t>() >= 16 && v.get<int64_t>() <= 256;
                spec["outputs"]["probes"]["probe_res"] = an_r ? v.get<int64_t>() : 48;
            }
            EXPECT_EQ(valid_against(doc, schema, spec), accepted(spec))
                << s.field() << " = " << v.dump() << ": the schema says " << valid_against(doc, schema, spec)
                << ", the server " << (accepted(spec) ? "accepts" : "refuses (" + error_of(spec, server) + ")");
            ++checked;
        }
    }
    for (const json& limits : {json{{"max_seconds", 0}}, json{{"max_seconds", 0.5}}, json{{"max_seconds", 1}},
                               json{{"max_seconds", "1"}}, json{{"max_seconds", 1e-9}}, json{{"max_attempts", 0}},
                               json{{"max_attempts", 1}}, json{{"max_attempts", 1.5}}, json{{"gpu", 1}}, json(3)}) {
        json spec = base;
        spec["limits"] = limits;
        EXPECT_EQ(valid_against(doc, schema, spec), accepted(spec)) << limits.dump();
    }
    for (const json& spec : {json{{"outputs", {{"lightmap", json::object()}}}}, json{{"scene", "s"}},
                             json{{"scene", "s"}, {"outputs", json::object()}},
                             json{{"scene", "s"}, {"outputs", {{"probes", json::object()}}}},
                             json{{"scene", "s"}, {"outputs", {{"lightmap", json::object()}}}, {"colour", 1}}})
        EXPECT_EQ(valid_against(doc, schema, spec), accepted(spec)) << spec.dump();
    // The canonical JSON the server stores (and JobStatus.spec shows) is valid too.
    for (const json& spec : {base, valid_spec()})
        EXPECT_TRUE(valid_against(doc, schema, to_json(parse_job_spec(spec)))) << to_json(parse_job_spec(spec)).dump();
    EXPECT_GT(checked, 300);
}

// ---------------------------------------------------------------------------
// README.md: the `lightfarm bake` option table is the catalog's

std::string cell_number(double v) {
    std::ostringstream s;
    s.precision(15);
    s << v;
    return s.str();
}

std::string values_cell(const Setting& s) {
    std::string v;
    switch (s.type) {
    case SettingType::Integer: v = "integer " + cell_number(s.min) + "–" + cell_number(s.max); break;
    case SettingType::Number:
        v = s.min_exclusive ? "number > " + cell_number(s.min) + ", ≤ " + cell_number(s.max)
                            : "number " + cell_number(s.min) + "–" + cell_number(s.max);
        break;
    case SettingType::Choice:
        for (const std::string& c : s.choices) v += (v.empty() ? "" : ", ") + ("`" + c + "`");
        break;
    case SettingType::Flag: v = std::string("flag: sets `") + (s.default_value == true ? "false" : "true") + "`"; break;
    case SettingType::MeshList: v = "glTF mesh indices: `0,3` (JSON `[0, 3]`)"; break;
    case SettingType::MeshScales: v = "glTF mesh index = scale: `3=2,5=0.25` (JSON `{\"3\": 2, \"5\": 0.25}`)"; break;
    case SettingType::Environment: v = "`R,G,B` (JSON `[R, G, B]`), or a map file (CLI)"; break;
    case SettingType::Positions: v = "a JSON file of `[{\"position\": [x, y, z]}, …]` (JSON: that array)"; break;
    }
    if (s.accepts_auto) v += ", or `auto`";
    return v;
}

std::string default_cell(const Setting& s) {
    if (s.default_value.is_null()) return "none";
    if (s.default_value.is_string()) return "`" + s.default_value.get<std::string>() + "`";
    return "`" + s.default_value.dump() + "`";
}

// A table cell: a `|` inside one would split it.
std::string cell(const std::string& text) {
    std::string out;
    for (char c : text) out += c == '|' ? std::string("\\|") : std::string(1, c);
    return out;
}

// The table README.md holds between its bake-options markers.
std::string bake_options_markdown() {
    std::string t = "| flag | JSON field | values | default | meaning |\n|---|---|---|---|---|\n";
    for (const Setting& s : setting_catalog()) {
        std::string meaning = s.help;
        if (!s.limit.empty()) meaning += "; a service caps it (`--limit " + s.limit + "=N`)";
        t += "| " + cell("`" + s.flag() + "`") + " | " + cell("`" + s.field() + "`") + " | " + cell(values_cell(s)) +
             " | " + cell(default_cell(s)) + " | " + cell(meaning) + " |\n";
    }
    return t;
}

TEST(Readme, BakeOptionTableIsTheCatalog) {
    const std::filesystem::path readme = repo_root() / "README.md";
    const std::string text = read_text(readme);
    ASSERT_FALSE(text.empty()) << "cannot read " << readme;
    const std::string begin = "<!-- bake-options:begin -->\n", end = "<!-- bake-options:end -->";
    const size_t from = text.find(begin);
    const size_t to = text.find(end);
    const std::string expected = bake_options_markdown();
    ASSERT_NE(from, std::string::npos) << "README.md has no " << begin << "paste this between the markers:\n\n"
                                       << begin << expected << end;
    ASSERT_NE(to, std::string::npos) << "README.md has no " << end;
    ASSERT_LT(from, to);
    const std::string table = text.substr(from + begin.size(), to - from - begin.size());
    EXPECT_EQ(table, expected) << "README.md's bake option table is not the catalog's; replace it with:\n\n"
                               << begin << expected << end << "\n";
    // Every setting's flag has its row.
    for (const Setting& s : setting_catalog())
        EXPECT_NE(table.find("`" + s.flag() + "`"), std::string::npos) << s.flag();
}

}  // namespace
}  // namespace lf::protocol

namespace lf::protocol {
namespace {

// Found by fuzzing: a sky component that overflows float32 was accepted, then
// stored as inf, written as null and refused when the worker read the spec.
TEST(FuzzFindings, ASkyBeyondFloatIsRefusedAtSubmit) {
    const nlohmann::json spec = {
        {"scene", "s"}, {"outputs", {{"lightmap", nlohmann::json::object()}}}, {"env", {1e39, 0, 0}}};
    EXPECT_THROW(parse_job_spec(spec), SpecError);
    const JobSpec ok =
        parse_job_spec({{"scene", "s"}, {"outputs", {{"lightmap", nlohmann::json::object()}}}, {"env", {3e38, 0, 0}}});
    EXPECT_NO_THROW(parse_job_spec(to_json(ok)));
}

// Found by fuzzing: "rays" as a float or a negative number was converted to
// uint64_t (undefined behaviour); such counts are not read.
TEST(FuzzFindings, ProgressCountsAreReadOnlyWhenTheyAreCounts) {
    EXPECT_EQ(progress_from_json({{"rays", 1e20}}).rays, 0u);
    EXPECT_EQ(progress_from_json({{"rays", -1.5}}).rays, 0u);
    EXPECT_EQ(progress_from_json({{"pass", -3}, {"rays", 7}}).pass, 0);
    EXPECT_EQ(progress_from_json({{"pass", 3}, {"rays", 7}}).rays, 7u);
    EXPECT_THROW(parse_worker_event({{"event", "snapshot"}, {"file", "a.exr"}, {"pass", 1.5}}), std::invalid_argument);
}

}  // namespace
// A failed or cancelled job has no ETA (a cancelled one kept its last);
// a queued, running or succeeded one shows what it has.
TEST(JobStatusJson, AJobThatEndedUnfinishedHasNoEta) {
    JobStatus s;
    s.progress.pass = 10;
    s.progress.seconds = 2.0;
    s.progress.eta_seconds = 30.0;
    for (JobState state :
         {JobState::Queued, JobState::Running, JobState::Succeeded, JobState::Failed, JobState::Cancelled}) {
        s.state = state;
        const bool ended_unfinished = state == JobState::Failed || state == JobState::Cancelled;
        EXPECT_EQ(to_json(s)["progress"]["eta_seconds"].is_null(), ended_unfinished) << to_string(state);
    }
}

}  // namespace lf::protocol
