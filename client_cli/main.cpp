// lightfarm: the command-line tool. A thin layer over the gi library: each
// command parses its options, calls the library, prints the result.
#include "args.h"
#include "remote.h"

#include "bake/bake.h"
#include "gpu/context.h"
#include "io/reference_error.h"
#include "scene/gltf_loader.h"
#include "scene/scene_summary.h"
#include "trace/raybench.h"

#include <unistd.h>

#include <cstdio>
#include <iostream>

namespace {

using lf::cli::Args;
using lf::cli::UsageError;

constexpr const char* kUsage = R"(usage: lightfarm COMMAND [options]

commands:
  inspect SCENE [--json]             what was loaded from a .gltf/.glb
  raybench SCENE [--device auto|gpu|cpu] [--seconds S]
                                     ray throughput of the tracer (JSON)
  bake SCENE --out DIR [--res N | --texel-density T] [--passes N]
       [--target-error E] [--time-limit S] [--device auto|gpu|cpu]
       [--seed N] [--scheme epochs|thesis|pathtrace] [--light-samples N]
       [--no-stitch] [--json]
                                     bake a radiosity-map lightmap
  compare BAKE.exr REFERENCE.exr [--mask MASK.pfm|.exr]
                                     error against a reference (JSON)
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

int compare(int argc, char** argv) {
    Args args(argc, argv, 2, {"--mask"}, {});
    if (args.positional().size() != 2) throw UsageError("compare takes BAKE.exr and REFERENCE.exr");
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

int bake(int argc, char** argv) {
    Args args(argc, argv, 2,
              {"--out", "--res", "--texel-density", "--passes", "--target-error", "--time-limit", "--device",
               "--seed", "--scheme", "--light-samples", "--subsamples"},
              {"--json", "--no-stitch", "--lightmap"});
    lf::BakeSettings settings;
    settings.scene = one_scene(args, "bake");
    if (!args.has("--out")) throw UsageError("bake needs --out DIR");
    settings.out = args.get("--out");
    if (args.has("--res") && args.has("--texel-density"))
        throw UsageError("give --res or --texel-density, not both");
    auto positive_int = [&](const char* key, double fallback, double max) {
        const double v = args.number(key, fallback);
        if (v < 1 || v > max || v != double(int(v)))
            throw UsageError(std::string(key) + " must be a whole number from 1 to " + std::to_string(int(max)));
        return int(v);
    };
    if (args.has("--res")) settings.resolution = positive_int("--res", 0, 16384);
    settings.texel_density = float(args.number("--texel-density", 0.0));
    if (settings.texel_density < 0.0f) throw UsageError("--texel-density must be positive");
    settings.stop.max_passes = positive_int("--passes", settings.stop.max_passes, 1 << 20);
    settings.stop.target_error = args.number("--target-error", 0.0);
    settings.stop.time_limit = args.number("--time-limit", 0.0);
    if (settings.stop.target_error < 0.0 || settings.stop.time_limit < 0.0)
        throw UsageError("--target-error and --time-limit must not be negative");
    settings.device = lf::parse_device_choice(args.get("--device", "auto"));
    settings.radiosity.seed = uint32_t(args.number("--seed", 1));
    settings.radiosity.scheme = lf::parse_radiosity_scheme(args.get("--scheme", "epochs"));
    settings.radiosity.light_samples = positive_int("--light-samples", 1, 1024);
    settings.subsamples_per_axis = positive_int("--subsamples", 2, 8);
    settings.stitch_seams = !args.flag("--no-stitch");

    const bool json = args.flag("--json");
    const bool terminal = !json && isatty(STDERR_FILENO);
    lf::bake_lightmap(settings, [&](const nlohmann::json& e) {
        if (json) {
            std::cout << e.dump() << std::endl;  // one object per line, flushed: the worker protocol
            return;
        }
        const std::string kind = e["event"];
        if (kind == "start") {
            std::cerr << "baking " << e["texels"] << " texels on " << e["renderer"].get<std::string>() << "\n";
        } else if (kind == "progress" && terminal) {
            draw_progress(e, settings.stop.max_passes);
        } else if (kind == "done") {
            if (terminal) std::cerr << "\n";
            std::cout << "done: " << e["pass"] << " passes, " << e["rays"] << " rays, " << e["seconds"]
                      << " s, error estimate " << e["error_estimate"] << "\nfiles in " << settings.out.string() << ":";
            for (const auto& f : e["files"]) std::cout << " " << f.get<std::string>();
            std::cout << "\n";
        }
    });
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
