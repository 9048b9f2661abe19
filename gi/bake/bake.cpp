#include "bake/bake.h"

#include "atlas/atlas.h"
#include "atlas/lightmapped_gltf.h"
#include "atlas/seams.h"
#include "atlas/texel_samples.h"
#include "io/image_files.h"
#include "scene/gltf_loader.h"
#include "trace/tracer.h"

#include <chrono>
#include <cstdio>

namespace lf {

namespace fs = std::filesystem;

namespace {

// The R, G, B channels of a layer ("" = combined, "direct.", "indirect.") as vec4 texels.
std::vector<glm::vec4> image_layer(const FloatImage& image, const std::string& layer) {
    const auto &r = image.at(layer + "R"), &g = image.at(layer + "G"), &b = image.at(layer + "B");
    std::vector<glm::vec4> out(r.size());
    for (size_t i = 0; i < r.size(); ++i) out[i] = glm::vec4(r[i], g[i], b[i], 0.0f);
    return out;
}

void set_image_layer(FloatImage& image, const std::string& layer, const std::vector<glm::vec4>& rgb) {
    auto &r = image.channel(layer + "R"), &g = image.channel(layer + "G"), &b = image.channel(layer + "B");
    for (size_t i = 0; i < rgb.size(); ++i) {
        r[i] = rgb[i].r;
        g[i] = rgb[i].g;
        b[i] = rgb[i].b;
    }
}

}  // namespace

nlohmann::json bake_lightmap(const BakeSettings& settings, const BakeEventSink& emit) {
    const auto start = std::chrono::steady_clock::now();
    Scene scene = load_scene(settings.scene);
    if (scene.emissive_triangle_count() == 0 && scene.lights.empty() &&
        settings.radiosity.background == glm::vec3(0.0f))
        throw std::runtime_error(settings.scene.string() +
                                 ": nothing to bake: the scene has no emissive surface, no punctual light "
                                 "and no environment was given");
    fs::create_directories(settings.out);

    // The atlas: the file's own TEXCOORD_1 when every primitive has it, else generated.
    AtlasOptions atlas_options;
    atlas_options.resolution = settings.resolution;
    atlas_options.texel_density = settings.texel_density;
    if (atlas_options.resolution == 0 && atlas_options.texel_density == 0.0f) atlas_options.resolution = 256;
    const AtlasReport atlas = prepare_lightmap_atlas(scene, atlas_options);
    const bool generated = atlas.generated;
    const TexelSamples texels = rasterize_texel_samples(scene, atlas.width, atlas.height, settings.subsamples_per_axis);

    GpuContext gpu(settings.device);
    const Tracer tracer(scene);
    RadiosityMapSettings radiosity = settings.radiosity;
    if (settings.stop.target_error > 0.0 && radiosity.converged_texel_error == 0.0)
        radiosity.converged_texel_error = 0.5 * settings.stop.target_error;
    RadiosityMapBaker baker(scene, texels, tracer, radiosity);
    const double prepare_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

    const nlohmann::json settings_json = {
        {"method", "radiosity_map"},
        {"scheme", to_string(radiosity.scheme)},
        {"atlas", {{"width", atlas.width}, {"height", atlas.height}, {"texel_density", atlas.texel_density},
                   {"generated", generated}, {"charts", atlas.charts}, {"utilisation", atlas.utilisation}}},
        {"light_samples", radiosity.light_samples},
        {"light_sampling", to_string(radiosity.light_sampling)},
        {"subsamples_per_texel", settings.subsamples_per_axis * settings.subsamples_per_axis},
        {"seed", radiosity.seed},
        {"max_passes", settings.stop.max_passes},
        {"target_error", settings.stop.target_error},
        {"time_limit", settings.stop.time_limit},
    };
    emit({{"event", "start"}, {"vendor", gpu.info().vendor}, {"renderer", gpu.info().renderer},
          {"texels", baker.covered_texels()}, {"triangles", scene.triangle_count()},
          {"prepare_seconds", prepare_seconds}, {"settings", settings_json}});

    // Smooth seams only: across a crease (a cube's edge) the two sides face
    // different ways and rightly differ.
    std::vector<SeamEdge> seams;
    for (const SeamEdge& e : find_seams(scene))
        if (e.smooth) seams.push_back(e);
    // The current lightmap, stitched; snapshot() already carries pass, rays, seconds.
    auto finished_image = [&]() {
        FloatImage image = baker.snapshot();
        image.string_attributes["lightfarm.renderer"] = gpu.info().renderer;
        image.string_attributes["lightfarm.settings"] = settings_json.dump();
        if (settings.stitch_seams && !seams.empty()) {
            for (const char* layer : {"", "direct.", "indirect."}) {
                std::vector<glm::vec4> rgb = image_layer(image, layer);
                stitch_seams(seams, rgb, image.width, image.height);
                set_image_layer(image, layer, rgb);
            }
        }
        return image;
    };

    std::vector<std::string> files;
    FloatImage last_snapshot;  // reused as the final image when the bake stops on a snapshot pass
    int last_snapshot_pass = 0;
    const PassStats final_stats = run_progressive(baker, settings.stop, [&](const PassStats& s, bool snapshot_due) {
        nlohmann::json progress = to_json(s);
        progress["event"] = "progress";
        emit(progress);
        if (snapshot_due) {
            const std::string name = snapshot_file_name("lightmap", s.pass, "exr");
            last_snapshot = finished_image();
            last_snapshot_pass = s.pass;
            write_exr(settings.out / name, last_snapshot);
            files.push_back(name);
            emit({{"event", "snapshot"}, {"file", name}, {"pass", s.pass}});
        }
    });

    const FloatImage final_image = last_snapshot_pass == final_stats.pass ? std::move(last_snapshot) : finished_image();
    write_exr(settings.out / "lightmap.exr", final_image);
    files.push_back("lightmap.exr");
    if (generated) {
        write_lightmapped_glb(settings.scene, scene, settings.out / "scene.lightmapped.glb");
        files.push_back("scene.lightmapped.glb");
    }

    nlohmann::json manifest = {
        {"scene", settings.scene.filename().string()},
        {"device", {{"vendor", gpu.info().vendor}, {"renderer", gpu.info().renderer}}},
        {"settings", settings_json},
        {"result", to_json(final_stats)},
        {"seams", {{"edges", seams.size()},
                   {"metric", seam_metric(seams, image_layer(final_image, ""), final_image.width, final_image.height)}}},
        {"files", nlohmann::json::object()},
    };
    for (const std::string& f : files) {
        manifest["files"][f] = f == "lightmap.exr" ? "final lightmap: RGB = irradiance/pi, layers direct, indirect, samples, error"
                               : f == "scene.lightmapped.glb" ? "the input scene with TEXCOORD_1 = the generated atlas"
                                                              : "intermediate lightmap snapshot";
    }
    files.push_back("manifest.json");
    manifest["files"]["manifest.json"] = "this file";
    write_file_atomic(settings.out / "manifest.json", manifest.dump(2) + "\n");

    nlohmann::json done = to_json(final_stats);
    done["event"] = "done";
    done["files"] = files;
    emit(done);
    return done;
}

}  // namespace lf
