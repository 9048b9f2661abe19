#include "bake/sh_bake.h"

#include "atlas/atlas.h"
#include "atlas/lightmapped_gltf.h"
#include "io/image_files.h"
#include "scene/gltf_loader.h"
#include "sh/environment.h"
#include "sh/sh_glb.h"
#include "sh/shading.h"
#include "sh/transfer_file.h"
#include "trace/tracer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <optional>
#include <set>

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

ShTexelReceivers sh_texel_receivers(const Scene& atlas_scene, const TexelSamples& texels,
                                    const std::vector<int>& receiver_meshes) {
    std::vector<bool> receives(atlas_scene.triangles.size(), receiver_meshes.empty());
    if (!receiver_meshes.empty())
        for (const PrimitiveInstance& inst : atlas_scene.instances)
            if (std::find(receiver_meshes.begin(), receiver_meshes.end(), inst.mesh) != receiver_meshes.end())
                for (uint32_t t = 0; t < inst.triangle_count; ++t) receives[inst.first_triangle + t] = true;
    ShTexelReceivers out;
    out.point_of_sample.assign(texels.samples.size(), -1);
    for (size_t k = 0; k < texels.samples.size(); ++k) {
        const TexelSample& sample = texels.samples[k];
        if (sample.triangle >= receives.size() || !receives[sample.triangle]) continue;
        glm::vec3 n = sample.normal;
        if (!(glm::dot(n, n) > 0.0f)) n = sample.geometric_normal;
        if (!(glm::dot(n, n) > 0.0f)) continue;  // a degenerate triangle with no normal: left untraced
        out.point_of_sample[k] = int64_t(out.points.size());
        out.points.push_back({sample.position, glm::normalize(n)});
    }
    return out;
}

FloatImage sh_texel_image(const TexelSamples& texels, const ShTexelReceivers& receivers,
                          const std::vector<ShCoefficients>& point_transfer, int bands) {
    if (bands < 1 || bands > kShMaxBands) throw std::invalid_argument("sh_texel_image: bands must be 1..4");
    if (point_transfer.size() != receivers.points.size())
        throw std::invalid_argument("sh_texel_image: one transfer vector per receiver point");
    const size_t pixels = size_t(texels.width) * size_t(texels.height);
    // Four coefficients per vec4 image (dilate() works on vec4), coverage in a fifth.
    std::vector<std::vector<glm::vec4>> groups(4, std::vector<glm::vec4>(pixels, glm::vec4(0.0f)));
    std::vector<glm::vec4> coverage(pixels, glm::vec4(0.0f));
    for (size_t i = 0; i < texels.covered_count(); ++i) {
        ShCoefficients mean{};
        const uint32_t first = texels.first_sample[i], count = texels.sample_count(i);
        for (uint32_t k = first; k < first + count; ++k) {
            const int64_t p = receivers.point_of_sample[k];
            const ShCoefficients t = p >= 0 ? point_transfer[size_t(p)]
                                   : glm::dot(texels.samples[k].normal, texels.samples[k].normal) > 0.0f
                                       ? unoccluded_transfer(glm::normalize(texels.samples[k].normal))
                                       : ShCoefficients{};
            for (int c = 0; c < kShMaxCoefficients; ++c) mean[c] += t[c] / float(count);
        }
        const uint32_t pixel = texels.texels[i];
        for (int g = 0; g < 4; ++g) groups[size_t(g)][pixel] = glm::vec4(mean[4 * g], mean[4 * g + 1], mean[4 * g + 2], mean[4 * g + 3]);
        coverage[pixel] = glm::vec4(1.0f);
    }
    for (auto& g : groups) dilate(texels, g);

    FloatImage image;
    image.width = texels.width;
    image.height = texels.height;
    for (int c = 0; c < bands * bands; ++c) {
        std::vector<float>& channel = image.channel("sh." + std::to_string(c));
        for (size_t p = 0; p < pixels; ++p) channel[p] = groups[size_t(c / 4)][p][c % 4];
    }
    std::vector<float>& covered = image.channel("coverage");
    for (size_t p = 0; p < pixels; ++p) covered[p] = coverage[p].x;
    image.number_attributes["lightfarm.bands"] = bands;
    image.string_attributes["lightfarm.sh_ordering"] =
        "sh.i = coefficient i = l(l+1)+m of the real orthonormal SH basis (gi/sh/sh_basis.h), y-up";
    return image;
}

nlohmann::json bake_sh(const ShBakeSettings& settings, const BakeEventSink& emit) {
    const auto start = std::chrono::steady_clock::now();
    if (settings.bands < 0 || settings.bands > kShMaxBands)
        throw std::invalid_argument("--sh-bands must be 1..4 or auto, not " + std::to_string(settings.bands));
    // Transfer does not depend on the lights: a scene without any is fine.
    const Scene scene = load_scene(settings.scene);
    // Occluder and receiver sets name glTF meshes: every one must be there.
    std::set<int> meshes;
    for (const PrimitiveInstance& i : scene.instances) meshes.insert(i.mesh);
    for (const auto& [option, list] : {std::pair{"--sh-occluders", &settings.transfer.occluder_meshes},
                                       std::pair{"--sh-receivers", &settings.transfer.receiver_meshes}})
        for (int m : *list)
            if (!meshes.count(m))
                throw std::invalid_argument(std::string(option) + ": mesh " + std::to_string(m) + " is not drawn by " +
                                            settings.scene.filename().string() + " (it has " +
                                            std::to_string(meshes.size()) + " meshes)");
    std::optional<Environment> environment;
    if (!settings.environment.empty()) environment = load_environment(settings.environment);
    fs::create_directories(settings.out);

    // --sh-per-texel: the lightmap's atlas on a copy of the scene (a generated
    // atlas splits vertices; the per-vertex outputs keep the input's), and its
    // texel sample points as extra receivers of the same baker.
    std::optional<Scene> atlas_scene;
    AtlasReport atlas;
    TexelSamples texels;
    ShTexelReceivers texel_receivers;
    if (settings.per_texel) {
        if (settings.per_texel_subsamples < 1 || settings.per_texel_subsamples > 8)
            throw std::invalid_argument("SH per texel: subsamples per axis must be 1..8");
        atlas_scene = scene;
        AtlasOptions atlas_options;
        atlas_options.resolution = settings.per_texel_resolution;
        atlas_options.texel_density = settings.per_texel_density;
        if (atlas_options.resolution == 0 && atlas_options.texel_density == 0.0f) atlas_options.resolution = 256;
        atlas = prepare_lightmap_atlas(*atlas_scene, atlas_options);
        texels = rasterize_texel_samples(*atlas_scene, atlas.width, atlas.height, settings.per_texel_subsamples);
        texel_receivers = sh_texel_receivers(*atlas_scene, texels, settings.transfer.receiver_meshes);
    }

    GpuContext gpu(settings.device);
    const Tracer tracer(scene);
    ShTransferBaker baker(scene, tracer, settings.transfer, texel_receivers.points);
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
        {"per_texel", settings.per_texel},
    };
    nlohmann::json per_texel_json;
    if (settings.per_texel) {
        per_texel_json = {
            {"file", "sh_transfer.exr"},
            {"atlas", {{"width", atlas.width}, {"height", atlas.height}, {"texel_density", atlas.texel_density},
                       {"generated", atlas.generated}, {"charts", atlas.charts}, {"utilisation", atlas.utilisation}}},
            {"subsamples_per_texel", settings.per_texel_subsamples * settings.per_texel_subsamples},
            {"covered_texels", texels.covered_count()},
            {"sample_points", texels.samples.size()},
            {"traced_points", texel_receivers.points.size()},
        };
        settings_json["per_texel_atlas"] = per_texel_json["atlas"];
        settings_json["per_texel_subsamples"] = settings.per_texel_subsamples;
    }
    nlohmann::json start_event = {{"event", "start"}, {"vendor", gpu.info().vendor}, {"renderer", gpu.info().renderer},
          {"vertices", scene.positions.size()}, {"unique_vertices", baker.unique_vertices()},
          {"receiver_vertices", baker.receiver_vertices()}, {"triangles", scene.triangle_count()},
          {"prepare_seconds", prepare_seconds}, {"settings", settings_json}};
    if (settings.per_texel) {
        start_event["texels"] = texels.covered_count();
        start_event["texel_points"] = texel_receivers.points.size();
    }
    emit(start_event);

    auto texel_image = [&](const ShVertexTransfer& t, int image_bands, const PassStats& s) {
        FloatImage image = sh_texel_image(texels, texel_receivers, t.point_coefficients, image_bands);
        image.string_attributes["lightfarm.renderer"] = gpu.info().renderer;
        image.string_attributes["lightfarm.settings"] = settings_json.dump();
        image.number_attributes["lightfarm.pass"] = s.pass;
        image.number_attributes["lightfarm.bounces"] = settings.transfer.bounces;
        image.number_attributes["lightfarm.samples_per_point"] = double(baker.samples_per_vertex());
        return image;
    };

    std::vector<std::string> files;
    const int snapshot_bands = settings.bands == 0 ? kShMaxBands : settings.bands;
    const PassStats final_stats = run_progressive(baker, settings.stop, [&](const PassStats& s, bool snapshot_due) {
        nlohmann::json progress = to_json(s);
        progress["event"] = "progress";
        emit(progress);
        if (snapshot_due) {
            const ShVertexTransfer t = baker.snapshot();
            const std::string name = snapshot_file_name("sh_transfer", s.pass, "bin");
            write_sh_transfer(settings.out / name,
                              transfer_by_primitive(scene, t.coefficients, snapshot_bands, settings.transfer.bounces),
                              ShEncoding::Float32);
            files.push_back(name);
            emit({{"event", "snapshot"}, {"file", name}, {"pass", s.pass}});
            if (settings.per_texel) {
                const std::string exr = snapshot_file_name("sh_transfer", s.pass, "exr");
                write_exr(settings.out / exr, texel_image(t, snapshot_bands, s));
                files.push_back(exr);
                emit({{"event", "snapshot"}, {"file", exr}, {"pass", s.pass}});
            }
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
    if (settings.per_texel) {
        write_exr(settings.out / "sh_transfer.exr", texel_image(transfer, bands, final_stats));
        files.push_back("sh_transfer.exr");
        if (atlas.generated) {
            write_lightmapped_glb(settings.scene, *atlas_scene, settings.out / "scene.lightmapped.glb");
            files.push_back("scene.lightmapped.glb");
        }
        nlohmann::json channels = nlohmann::json::array();
        for (int c = 0; c < bands * bands; ++c) channels.push_back("sh." + std::to_string(c));
        channels.push_back("coverage");
        per_texel_json["channels"] = channels;
    }
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
        {"per_texel", settings.per_texel ? per_texel_json : nlohmann::json(false)},
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
            : f == "sh_transfer.exr"      ? "per-texel SH transfer in the lightmap atlas: channels sh.0 … sh.{bands²-1} "
                                            "(coefficient l(l+1)+m), coverage; dilated past chart borders"
            : f == "scene.lightmapped.glb" ? "the input scene with TEXCOORD_1 = the generated atlas (of sh_transfer.exr)"
            : f.ends_with(".exr")         ? "intermediate per-texel SH transfer snapshot"
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
