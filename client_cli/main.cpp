// lightfarm: the command-line tool. A thin layer over the gi library: each
// command parses its options, calls the library, prints the result.
#include "args.h"
#include "remote.h"

#include "bake/bake.h"
#include "bake/sh_bake.h"
#include "sh/sh_glb.h"
#include "sh/transfer_file.h"
#include "gpu/context.h"
#include "io/reference_error.h"
#include "scene/gltf_loader.h"
#include "scene/scene_summary.h"
#include "trace/raybench.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <iostream>

namespace {

using lf::cli::Args;
using lf::cli::UsageError;

constexpr const char* kUsage = R"(usage: lightfarm COMMAND [options]

commands:
  inspect SCENE [--json]             what was loaded from a .gltf/.glb
  raybench SCENE [--device auto|gpu|cpu] [--seconds S]
                                     ray throughput of the tracer (JSON)
  bake SCENE --out DIR [--lightmap] [--sh] [--device auto|gpu|cpu] [--seed N] [--json]
       lightmap (the default): [--res N | --texel-density T] [--passes N]
         [--target-error E] [--time-limit S] [--scheme epochs|thesis|pathtrace]
         [--light-samples N] [--light-sampling mis|area|solid-angle] [--no-stitch]
       SH transfer (--sh): [--sh-bands 1..4|auto] [--sh-bounces N] [--env FILE|R,G,B]
         [--sh-window none|hanning|lanczos] [--sh-passes N] [--sh-target-error E]
         [--sh-time-limit S] [--sh-occluders MESHES] [--sh-receivers MESHES]
         [--sh-per-texel: transfer per lightmap texel (--res) -> sh_transfer.exr]
                                     bake a radiosity-map lightmap and/or SH transfer
  sh-shade TRANSFER ENV --out shaded.glb [--scene SCENE] [--sh-window W]
                                     vertex colours = SH transfer x environment
  devices [--json]                   the EGL devices (GPUs, llvmpipe) a bake can use
  compare BAKE.exr REFERENCE.exr [--mask MASK.pfm|.exr]
  compare TRANSFER.bin REFERENCE.bin error against a reference (JSON)
)";

std::string one_scene(const Args& args, const char* command) {
    if (args.positional().size() != 1)
        throw UsageError(std::string(command) + " takes exactly one SCENE argument");
    return args.positional()[0];
}

int inspect(int argc, char** argv) {
    Args args(argc, argv, 2, {}, {"--json"});
    const lf::Scene scene = lf::load_scene(one_scene(args, "inspect"));
    if (args.flag("--json")) std::cout << lf::summarize(scene).dump(2) << "\n";
    else std::cout << lf::format_summary(scene);
    return 0;
}

int raybench(int argc, char** argv) {
    Args args(argc, argv, 2, {"--device", "--seconds"}, {});
    const lf::Scene scene = lf::load_scene(one_scene(args, "raybench"));
    lf::GpuContext gpu(lf::parse_device_choice(args.get("--device", "auto")));
    lf::RaybenchOptions options;
    options.min_seconds = args.number("--seconds", options.min_seconds);
    std::cout << lf::run_raybench(gpu, scene, options).dump(2) << "\n";
    return 0;
}

// What the service asks to size its worker pool: one worker per GPU.
int devices(int argc, char** argv) {
    Args args(argc, argv, 2, {}, {"--json"});
    const std::vector<lf::EglDeviceInfo> list = lf::list_egl_devices();
    int gpus = 0;
    nlohmann::json out = {{"devices", nlohmann::json::array()}};
    for (const lf::EglDeviceInfo& d : list) {
        out["devices"].push_back({{"software", d.software}, {"gpu_index", d.gpu_index}});
        gpus += d.software ? 0 : 1;
    }
    out["gpus"] = gpus;
    if (args.flag("--json")) {
        std::cout << out.dump() << "\n";
    } else {
        std::cout << gpus << " GPU(s)";
        for (const lf::EglDeviceInfo& d : list)
            std::cout << (d.software ? ", software (llvmpipe)" : ", gpu:" + std::to_string(d.gpu_index));
        std::cout << "\n";
    }
    return 0;
}

// Two SH transfer files of the same scene: relative RMSE of the coefficients
// (over the bands both hold) against the reference's RMS coefficient.
int compare_sh_transfer(const std::string& bake_path, const std::string& reference_path) {
    const lf::ShTransferFile bake = lf::read_sh_transfer(bake_path);
    const lf::ShTransferFile reference = lf::read_sh_transfer(reference_path);
    if (bake.primitives.size() != reference.primitives.size())
        throw std::runtime_error(bake_path + " and " + reference_path + " hold different primitives");
    const int coefficients = std::min(bake.bands, reference.bands) * std::min(bake.bands, reference.bands);
    double sum_sq = 0.0, sum_ref_sq = 0.0;
    size_t vertices = 0;
    for (size_t p = 0; p < bake.primitives.size(); ++p) {
        const auto &a = bake.primitives[p].vertices, &b = reference.primitives[p].vertices;
        if (a.size() != b.size()) throw std::runtime_error("primitive " + std::to_string(p) + ": vertex counts differ");
        for (size_t v = 0; v < a.size(); ++v)
            for (int i = 0; i < coefficients; ++i) {
                sum_sq += double(a[v][i] - b[v][i]) * double(a[v][i] - b[v][i]);
                sum_ref_sq += double(b[v][i]) * double(b[v][i]);
            }
        vertices += a.size();
    }
    std::cout << nlohmann::json{{"relative_rmse", sum_ref_sq > 0.0 ? std::sqrt(sum_sq / sum_ref_sq) : 0.0},
                                {"vertices", vertices}, {"coefficients", coefficients}}
                     .dump()
              << "\n";
    return 0;
}

int compare(int argc, char** argv) {
    Args args(argc, argv, 2, {"--mask"}, {});
    if (args.positional().size() != 2) throw UsageError("compare takes BAKE and REFERENCE (.exr lightmaps or .bin SH transfer)");
    const auto is_bin = [](const std::string& f) { return f.size() > 4 && f.substr(f.size() - 4) == ".bin"; };
    if (is_bin(args.positional()[0])) return compare_sh_transfer(args.positional()[0], args.positional()[1]);
    const lf::FloatImage bake = lf::read_exr(args.positional()[0]);
    const lf::FloatImage reference = lf::read_exr(args.positional()[1]);
    lf::FloatImage mask;
    if (args.has("--mask")) {
        const std::string m = args.get("--mask");
        mask = m.size() > 4 && m.substr(m.size() - 4) == ".pfm" ? lf::read_pfm(m) : lf::read_exr(m);
    }
    const lf::ReferenceError e = lf::compare_to_reference(bake, reference, args.has("--mask") ? &mask : nullptr);
    nlohmann::json out = {{"relative_rmse", e.relative_rmse}, {"rmse", e.rmse}, {"bias", e.bias},
                          {"reference_mean", e.reference_mean}, {"texels", e.texels}};
    for (const char* key : {"lightfarm.pass", "lightfarm.rays", "lightfarm.seconds", "lightfarm.errorEstimate"}) {
        auto it = bake.number_attributes.find(key);
        if (it != bake.number_attributes.end()) out[std::string(key).substr(10)] = it->second;
    }
    std::cout << out.dump() << "\n";
    return 0;
}

// One progress line, redrawn in place on a terminal.
void draw_progress(const nlohmann::json& e, int max_passes) {
    const int pass = e["pass"];
    const int width = 30;
    const int filled = std::min(width, pass * width / std::max(1, max_passes));
    std::fprintf(stderr, "\r[%s%s] pass %d/%d  %.3g rays  %.1f s  error %.2f%%  ",
                 std::string(size_t(filled), '#').c_str(), std::string(size_t(width - filled), '.').c_str(), pass,
                 max_passes, double(e["rays"].get<uint64_t>()), e["seconds"].get<double>(),
                 100.0 * e["error_estimate"].get<double>());
}

// Prints bake events: JSON lines (the worker protocol) or a progress bar.
class BakeReporter {
public:
    BakeReporter(bool json, int max_passes) : json_(json), terminal_(!json && isatty(STDERR_FILENO)), max_passes_(max_passes) {}

    void operator()(const nlohmann::json& e) {
        if (json_) {
            std::cout << e.dump() << std::endl;  // one object per line, flushed
            return;
        }
        const std::string kind = e["event"];
        if (kind == "start") {
            std::cerr << "baking " << e.value("texels", e.value("vertices", 0)) << (e.contains("texels") ? " texels" : " vertices")
                      << " on " << e["renderer"].get<std::string>() << "\n";
        } else if (kind == "progress" && terminal_) {
            draw_progress(e, max_passes_);
        } else if (kind == "done") {
            if (terminal_) std::cerr << "\n";
            std::cout << "done: " << e["pass"] << " passes, " << e["rays"] << " rays, " << e["seconds"]
                      << " s, error estimate " << e["error_estimate"] << "\n";
        }
    }

private:
    bool json_, terminal_;
    int max_passes_;
};

int bake(int argc, char** argv) {
    Args args(argc, argv, 2,
              {"--out", "--res", "--texel-density", "--passes", "--target-error", "--time-limit", "--device",
               "--seed", "--scheme", "--light-samples", "--light-sampling", "--subsamples", "--sh-bands", "--sh-bounces", "--env",
               "--sh-window", "--sh-passes", "--sh-target-error", "--sh-time-limit", "--sh-occluders", "--sh-receivers"},
              {"--json", "--no-stitch", "--lightmap", "--sh", "--sh-per-texel"});
    const std::string scene = one_scene(args, "bake");
    if (!args.has("--out")) throw UsageError("bake needs --out DIR");
    const std::filesystem::path out = args.get("--out");
    auto whole = [&](const char* key, double fallback, double lo, double hi) {
        const double v = args.number(key, fallback);
        if (v < lo || v > hi || v != double(int64_t(v)))
            throw UsageError(std::string(key) + " must be a whole number from " + std::to_string(int64_t(lo)) +
                             " to " + std::to_string(int64_t(hi)));
        return int(v);
    };
    auto non_negative = [&](const char* key) {
        const double v = args.number(key, 0.0);
        if (v < 0.0) throw UsageError(std::string(key) + " must not be negative");
        return v;
    };
    const bool want_sh = args.flag("--sh");
    const bool want_lightmap = args.flag("--lightmap") || !want_sh;
    const lf::DeviceChoice device = lf::parse_device_choice(args.get("--device", "auto"));
    const uint32_t seed = uint32_t(whole("--seed", 1, 0, 4294967295.0));

    lf::BakeSettings lightmap;
    lightmap.scene = scene;
    lightmap.out = out;
    lightmap.device = device;
    if (args.has("--res") && args.has("--texel-density"))
        throw UsageError("give --res or --texel-density, not both");
    if (args.has("--res")) lightmap.resolution = whole("--res", 0, 1, 16384);
    lightmap.texel_density = float(non_negative("--texel-density"));
    lightmap.stop.max_passes = whole("--passes", lightmap.stop.max_passes, 1, 1 << 24);
    lightmap.stop.target_error = non_negative("--target-error");
    lightmap.stop.time_limit = non_negative("--time-limit");
    lightmap.radiosity.seed = seed;
    lightmap.radiosity.scheme = lf::parse_radiosity_scheme(args.get("--scheme", "epochs"));
    lightmap.radiosity.light_samples = whole("--light-samples", 1, 1, 1024);
    lightmap.radiosity.light_sampling = lf::parse_light_sampling(args.get("--light-sampling", "mis"));
    lightmap.subsamples_per_axis = whole("--subsamples", 2, 1, 8);
    lightmap.stitch_seams = !args.flag("--no-stitch");
    if (want_lightmap && args.has("--env")) {
        // A lightmap's environment is a uniform sky for now: rays that escape see this radiance.
        const std::string env = args.get("--env");
        float r, g, b;
        char tail;
        if (std::sscanf(env.c_str(), "%f,%f,%f%c", &r, &g, &b, &tail) != 3 || r < 0 || g < 0 || b < 0)
            throw UsageError("--env for a lightmap must be a uniform sky radiance R,G,B (an environment map works with --sh only), not '" + env + "'");
        lightmap.radiosity.background = glm::vec3(r, g, b);
    }

    lf::ShBakeSettings sh;
    sh.scene = scene;
    sh.out = out;
    sh.device = device;
    sh.environment = args.get("--env", "");
    sh.window = lf::parse_sh_window(args.get("--sh-window", "none"));
    sh.bands = args.get("--sh-bands", "4") == "auto" ? 0 : whole("--sh-bands", 4, 1, 4);
    sh.transfer.bounces = whole("--sh-bounces", 0, 0, 4);
    sh.transfer.seed = seed;
    sh.stop.max_passes = whole("--sh-passes", sh.stop.max_passes, 1, 1 << 24);
    sh.stop.target_error = non_negative("--sh-target-error");
    sh.stop.time_limit = non_negative("--sh-time-limit");
    // The seed's occluder and receiver sets (§3.1): glTF mesh indices, "0,3,4".
    auto mesh_list = [&](const char* key) {
        std::vector<int> meshes;
        const std::string text = args.get(key);
        size_t at = 0;
        while (at < text.size()) {
            const size_t comma = std::min(text.find(',', at), text.size());
            const std::string item = text.substr(at, comma - at);
            if (item.empty() || item.find_first_not_of("0123456789") != std::string::npos || item.size() > 9)
                throw UsageError(std::string(key) + " takes glTF mesh indices like 0,3,4, not '" + text + "'");
            meshes.push_back(std::stoi(item));
            at = comma + 1;
        }
        return meshes;
    };
    if (args.has("--sh-occluders")) sh.transfer.occluder_meshes = mesh_list("--sh-occluders");
    if (args.has("--sh-receivers")) sh.transfer.receiver_meshes = mesh_list("--sh-receivers");
    sh.per_texel = args.flag("--sh-per-texel");
    if (sh.per_texel && !want_sh) throw UsageError("--sh-per-texel needs --sh");
    sh.per_texel_resolution = lightmap.resolution;  // --res (0: from --texel-density, or 256)
    sh.per_texel_density = lightmap.texel_density;  // --texel-density
    if (args.has("--subsamples")) sh.per_texel_subsamples = lightmap.subsamples_per_axis;

    BakeReporter report(args.flag("--json"), want_lightmap ? lightmap.stop.max_passes : sh.stop.max_passes);
    // Both outputs: one "done" at the very end, listing every file, so a
    // reader of the event stream sees one bake.
    std::vector<std::string> files;
    auto pass_through_all_but_done = [&](const nlohmann::json& e) {
        if (e["event"] == "done") {
            for (const auto& f : e["files"]) files.push_back(f);
            return;
        }
        report(e);
    };
    nlohmann::json done;
    if (want_lightmap) done = lf::bake_lightmap(lightmap, want_sh ? lf::BakeEventSink(pass_through_all_but_done) : lf::BakeEventSink(std::ref(report)));
    if (want_sh) {
        done = lf::bake_sh(sh, pass_through_all_but_done);
        std::sort(files.begin(), files.end());
        files.erase(std::unique(files.begin(), files.end()), files.end());
        done["files"] = files;
        report(done);
    }
    if (!args.flag("--json")) {
        std::cout << "files in " << out.string() << ":";
        for (const auto& f : done["files"]) std::cout << " " << f.get<std::string>();
        std::cout << "\n";
    }
    return 0;
}

int sh_shade(int argc, char** argv) {
    Args args(argc, argv, 2, {"--out", "--scene", "--sh-window"}, {});
    if (args.positional().size() != 2) throw UsageError("sh-shade takes TRANSFER and ENV");
    if (!args.has("--out")) throw UsageError("sh-shade needs --out shaded.glb");
    lf::ShShadeOptions options;
    options.scene = args.get("--scene", "");
    options.window = lf::parse_sh_window(args.get("--sh-window", "none"));
    std::cout << lf::shade_sh_glb(args.positional()[0], args.positional()[1], args.get("--out"), options).dump(2)
              << "\n";
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc < 2 || std::string(argv[1]) == "--help" || std::string(argv[1]) == "help") {
        std::cout << kUsage << lf::cli::kRemoteUsage;
        return argc < 2 ? 2 : 0;
    }
    const std::string command = argv[1];
    try {
        if (lf::cli::is_remote_command(command)) return lf::cli::run_remote_command(command, argc, argv);
        if (command == "inspect") return inspect(argc, argv);
        if (command == "raybench") return raybench(argc, argv);
        if (command == "bake") return bake(argc, argv);
        if (command == "compare") return compare(argc, argv);
        if (command == "devices") return devices(argc, argv);
        if (command == "sh-shade") return sh_shade(argc, argv);
        throw UsageError("unknown command '" + command + "'");
    } catch (const std::invalid_argument& e) {  // a bad option value
        std::cerr << "lightfarm: " << e.what() << "\n";
        return 2;
    } catch (const UsageError& e) {
        std::cerr << "lightfarm: " << e.what() << "\n" << kUsage << lf::cli::kRemoteUsage;
        return 2;
    } catch (const std::exception& e) {
        // One line, with the context the thrower put in (file, object, shader).
        std::cerr << "lightfarm " << command << ": error: " << e.what() << "\n";
        return 1;
    }
}
