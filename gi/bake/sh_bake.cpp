#include "bake/sh_bake.h"

#include "io/image_files.h"
#include "scene/gltf_loader.h"
#include "sh/environment.h"
#include "sh/sh_glb.h"
#include "sh/shading.h"
#include "sh/transfer_file.h"
#include "trace/tracer.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <optional>

namespace lf {

namespace fs = std::filesystem;

namespace {

// What half floats cost: the largest and the RMS coefficient error, relative
// to the RMS coefficient (over the bands written).
nlohmann::json compact_error(const ShTransferFile& exact, const ShTransferFile& compact) {
    double max_error = 0.0, sum_sq_error = 0.0, sum_sq = 0.0;
    const int c = exact.bands * exact.bands;
    for (size_t p = 0; p < exact.primitives.size(); ++p)
        for (size_t v = 0; v < exact.primitives[p].vertices.size(); ++v)
            for (int i = 0; i < c; ++i) {
                const double a = exact.primitives[p].vertices[v][i], b = compact.primitives[p].vertices[v][i];
                max_error = std::max(max_error, std::abs(a - b));
                sum_sq_error += (a - b) * (a - b);
                sum_sq += a * a;
            }
    const double rms = sum_sq > 0.0 ? std::sqrt(sum_sq_error / sum_sq) : 0.0;
    return {{"max_abs_error", max_error}, {"relative_rms_error", rms}};
}

}  // namespace

nlohmann::json bake_sh(const ShBakeSettings& settings, const BakeEventSink& emit) {
    const auto start = std::chrono::steady_clock::now();
    if (settings.bands < 0 || settings.bands > kShMaxBands)
        throw std::invalid_argument("--sh-bands must be 1..4 or auto, not " + std::to_string(settings.bands));
    // Transfer does not depend on the lights: a scene without any is fine.
    const Scene scene = load_scene(settings.scene);
    std::optional<Environment> environment;
    if (!settings.environment.empty()) environment = load_environment(settings.environment);
    fs::create_directories(settings.out);

    GpuContext gpu(settings.device);
    const Tracer tracer(scene);
    ShTransferBaker baker(scene, tracer, settings.transfer);
    const double prepare_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

    nlohmann::json settings_json = {
        {"method", "sh_transfer"},
        {"bands", settings.bands == 0 ? nlohmann::json("auto") : nlohmann::json(settings.bands)},
        {"auto_bands_error", settings.auto_bands_error},
        {"bounces", settings.transfer.bounces},
        {"samples_per_pass", settings.transfer.samples_per_pass},
        {"near", settings.transfer.near},
        {"far", settings.transfer.far},
        {"occluder_meshes", settings.transfer.occluder_meshes},
        {"receiver_meshes", settings.transfer.receiver_meshes},
        {"environment", settings.environment},
        {"window", to_string(settings.window)},
        {"seed", settings.transfer.seed},
        {"max_passes", settings.stop.max_passes},
        {"target_error", settings.stop.target_error},
        {"time_limit", settings.stop.time_limit},
    };
    emit({{"event", "start"}, {"vendor", gpu.info().vendor}, {"renderer", gpu.info().renderer},
          {"vertices", scene.positions.size()}, {"unique_vertices", baker.unique_vertices()},
          {"receiver_vertices", baker.receiver_vertices()}, {"triangles", scene.triangle_count()},
          {"prepare_seconds", prepare_seconds}, {"settings", settings_json}});

    std::vector<std::string> files;
    const int snapshot_bands = settings.bands == 0 ? kShMaxBands : settings.bands;
    const PassStats final_stats = run_progressive(baker, settings.stop, [&](const PassStats& s, bool snapshot_due) {
        nlohmann::json progress = to_json(s);
        progress["event"] = "progress";
        emit(progress);
        if (snapshot_due) {
            const std::string name = snapshot_file_name("sh_transfer", s.pass, "bin");
            write_sh_transfer(settings.out / name,
                              transfer_by_primitive(scene, baker.snapshot().coefficients, snapshot_bands,
                                                    settings.transfer.bounces),
                              ShEncoding::Float32);
            files.push_back(name);
            emit({{"event", "snapshot"}, {"file", name}, {"pass", s.pass}});
        }
    });

    const ShVertexTransfer transfer = baker.snapshot();
    // Bands: as asked, or the fewest that shade within auto_bands_error of 4
    // under the environment (a uniform sky without one).
    const EnvironmentSh band_light = project_environment(environment ? *environment : uniform_sky());
    nlohmann::json band_errors = nlohmann::json::object();
    for (int b = 1; b <= kShMaxBands; ++b)
        band_errors[std::to_string(b)] = band_truncation_error(transfer.coefficients, band_light, b);
    const int bands = settings.bands > 0 ? settings.bands
                                         : choose_band_count(transfer.coefficients, band_light, settings.auto_bands_error);

    const ShTransferFile file = transfer_by_primitive(scene, transfer.coefficients, bands, settings.transfer.bounces);
    const std::string exact_bytes = encode_sh_transfer(file, ShEncoding::Float32);
    const std::string half_bytes = encode_sh_transfer(file, ShEncoding::Float16);
    write_file_atomic(settings.out / "sh_transfer.bin", exact_bytes);
    write_file_atomic(settings.out / "sh_transfer.half.bin", half_bytes);
    files.push_back("sh_transfer.bin");
    files.push_back("sh_transfer.half.bin");
    write_sh_glb(settings.scene, scene, transfer.coefficients, bands, settings.out / "scene.sh.glb");
    files.push_back("scene.sh.glb");
    nlohmann::json env_json;
    if (environment) {
        EnvironmentSh sh = project_environment(*environment, settings.window, bands);
        env_json = to_json(sh);
        write_file_atomic(settings.out / "env_sh.json", env_json.dump(2) + "\n");
        files.push_back("env_sh.json");
    }

    // The manifest's "sh" section; a lightmap bake into the same directory keeps its own.
    nlohmann::json manifest = nlohmann::json::object();
    if (std::ifstream in(settings.out / "manifest.json"); in) {
        try {
            manifest = nlohmann::json::parse(in);
        } catch (const std::exception&) {
            manifest = nlohmann::json::object();
        }
    }
    manifest["scene"] = settings.scene.filename().string();
    manifest["device"] = {{"vendor", gpu.info().vendor}, {"renderer", gpu.info().renderer}};
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    manifest["sh"] = {
        {"settings", settings_json},
        {"result", to_json(final_stats)},
        {"bands", bands},
        {"band_errors", {{"light", band_light.source}, {"relative_rms_vs_4_bands", band_errors}}},
        {"samples_per_vertex", baker.samples_per_vertex()},
        {"vertices", scene.positions.size()},
        {"unique_vertices", baker.unique_vertices()},
        {"receiver_vertices", baker.receiver_vertices()},
        {"total_seconds", seconds},
        {"compact", {{"file", "sh_transfer.half.bin"}, {"encoding", "float16"}, {"bytes", half_bytes.size()},
                     {"float32_bytes", exact_bytes.size()},
                     {"error", compact_error(file, decode_sh_transfer(half_bytes, "sh_transfer.half.bin"))}}},
    };
    if (!manifest.contains("files")) manifest["files"] = nlohmann::json::object();
    for (const std::string& f : files) {
        manifest["files"][f] =
            f == "sh_transfer.bin"        ? "per-vertex SH transfer, float32 (format: gi/sh/transfer_file.h)"
            : f == "sh_transfer.half.bin" ? "per-vertex SH transfer, float16"
            : f == "scene.sh.glb"         ? "the input scene with _SH_TRANSFER_k VEC4 vertex attributes"
            : f == "env_sh.json"          ? "the environment's SH coefficients (16 RGB), with its window"
                                          : "intermediate SH transfer snapshot (float32)";
    }
    manifest["files"]["manifest.json"] = "this file";
    files.push_back("manifest.json");
    write_file_atomic(settings.out / "manifest.json", manifest.dump(2) + "\n");

    nlohmann::json done = to_json(final_stats);
    done["event"] = "done";
    done["files"] = files;
    done["bands"] = bands;
    emit(done);
    return done;
}

}  // namespace lf
