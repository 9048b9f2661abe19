#include "bake/radiosity_map_method.h"

#include "bake/atlas_files.h"
#include "io/image_files.h"

#include <future>
#include <memory>

namespace lf {

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

// Across a crease (a cube's edge) the two sides face different ways and
// rightly differ: only smooth seams are stitched.
std::vector<SeamEdge> smooth_seams(const Scene& scene) {
    std::vector<SeamEdge> seams;
    for (const SeamEdge& e : find_seams(scene))
        if (e.smooth) seams.push_back(e);
    return seams;
}

}  // namespace

RadiosityMapSettings radiosity_settings(const protocol::BakeSettings& settings,
                                        const std::optional<Environment>& environment) {
    const protocol::OutputSettings& l = *settings.output("lightmap");
    RadiosityMapSettings r;
    r.scheme = parse_radiosity_scheme(l.choice("scheme"));
    r.light_samples = l.integer("light_samples");
    r.light_sampling = parse_light_sampling(l.choice("light_sampling"));
    r.seed = settings.seed;
    r.environment = environment ? &*environment : nullptr;
    // Adaptive sampling: a texel well below the target stops tracing.
    if (l.stop().target_error > 0.0) r.converged_texel_error = 0.5 * l.stop().target_error;
    r.directional = l.flag("directional");
    r.passes_per_dispatch = l.integer_or_auto("passes_per_dispatch").value_or(0);
    return r;
}

RadiosityMapMethod::RadiosityMapMethod(const PreparedScene& prepared, const protocol::BakeSettings& settings)
    : prepared_(prepared),
      stop_(stop_rule_from(settings.output("lightmap")->stop())),
      baker_(*prepared.atlas_scene, prepared.texels, *prepared.tracer,
             radiosity_settings(settings, prepared.environment)),
      seams_(smooth_seams(*prepared.atlas_scene)) {
    const protocol::OutputSettings& lightmap = *settings.output("lightmap");
    if (lightmap.flag("stitch") && !seams_.empty())
        stitcher_.emplace(seams_, prepared.atlas.width, prepared.atlas.height);
    if (lightmap.flag("denoise")) denoiser_.emplace(*prepared.atlas_scene, prepared.texels);
    const RadiosityMapSettings r = radiosity_settings(settings, std::nullopt);
    settings_json_ = {
        {"method", "radiosity_map"},
        {"scheme", to_string(r.scheme)},
        {"atlas", atlas_json(prepared.atlas)},
        {"light_samples", r.light_samples},
        {"light_sampling", to_string(r.light_sampling)},
        {"subsamples_per_texel", settings.atlas.subsamples * settings.atlas.subsamples},
        {"stitch", lightmap.flag("stitch")},
        {"denoise", lightmap.flag("denoise")},
        {"directional", lightmap.flag("directional")},
        {"seed", r.seed},
        {"max_passes", stop_.max_passes},
        {"target_error", stop_.target_error},
        {"time_limit", stop_.time_limit},
    };
}

nlohmann::json RadiosityMapMethod::description() const {
    return {{"texels", baker_.covered_texels()},
            {"texels_moved_out_of_geometry", baker_.texels_moved_out_of_geometry()},
            {"texels_cut_by_geometry", baker_.texels_cut_by_geometry()},
            // Not a setting of the result (a state of any count resumes):
            // follows the device where auto.
            {"passes_per_dispatch", baker_.passes_per_dispatch()},
            {"settings", settings_json_}};
}

uint64_t RadiosityMapMethod::rays_per_pass() const { return baker_.rays_per_pass(); }

FloatImage RadiosityMapMethod::stitched_image(const RadiosityMapBaker::Readback& readback, bool during_passes,
                                              const LightmapDenoiser* denoiser) const {
    FloatImage image = baker_.image(readback);
    if (denoiser) denoiser->denoise(image);
    image.string_attributes["lightfarm.renderer"] = prepared_.gpu->info().renderer;
    image.string_attributes["lightfarm.settings"] = settings_json_.dump();
    if (stitcher_) {
        // Each layer is its own solve of the same system: one thread each,
        // except while a software renderer's passes use every core (more
        // threads would only take them from the passes).
        const bool in_parallel = !(during_passes && prepared_.gpu->info().is_software);
        std::vector<std::pair<std::string, std::vector<glm::vec4>>> layers;
        for (const char* layer : {"", "direct.", "indirect.", "raw.", "L1x.", "L1y.", "L1z."})
            if (image.channels.count(std::string(layer) + "R")) layers.emplace_back(layer, image_layer(image, layer));
        std::vector<std::future<void>> solves;
        for (auto& [layer, rgb] : layers) {
            const bool irradiance = layer[0] != 'L';  // the L1 vectors' components are signed
            solves.push_back(
                std::async(in_parallel ? std::launch::async : std::launch::deferred,
                           [this, &rgb = rgb, irradiance] { stitcher_->stitch(rgb, 0.1f, 64, irradiance); }));
        }
        for (std::future<void>& solve : solves) solve.get();
        for (const auto& [layer, rgb] : layers) set_image_layer(image, layer, rgb);
    }
    return image;
}

SnapshotWrite RadiosityMapMethod::snapshot(const std::filesystem::path& dir, const PassStats& stats) {
    auto readback = std::make_shared<RadiosityMapBaker::Readback>(baker_.read_back());
    return [this, dir, readback, pass = stats.pass] {
        const std::string name = snapshot_file_name("lightmap", pass, "exr");
        FloatImage image = stitched_image(*readback, /*during_passes=*/true);
        write_exr(dir / name, image);
        last_snapshot_ = std::move(image);
        last_snapshot_pass_ = pass;
        return std::vector<std::string>{name};
    };
}

MethodResult RadiosityMapMethod::finish(const std::filesystem::path& dir, const PassStats& stats) {
    // The final file is the last snapshot when it shows the last pass (and
    // nothing is filtered: snapshots are not; the filter needs the GL thread).
    auto final_image = std::make_shared<const FloatImage>(
        last_snapshot_pass_ == stats.pass && !denoiser_
            ? std::move(last_snapshot_)
            : stitched_image(baker_.read_back(), /*during_passes=*/false, denoiser_ ? &*denoiser_ : nullptr));
    const FloatImage& image = *final_image;
    MethodResult result;
    result.files = write_atlas_exr(dir, "lightmap.exr", image, prepared_.atlas.pages);
    result.image = std::move(final_image);
    result.manifest = {
        {"settings", settings_json_},
        {"texels",
         {{"covered", baker_.covered_texels()},
          {"moved_out_of_geometry", baker_.texels_moved_out_of_geometry()},
          {"cut_by_geometry", baker_.texels_cut_by_geometry()}}},
        {"result", protocol::to_json(stats)},
        {"seams",
         {{"edges", seams_.size()},
          {"metric", seam_metric(seams_, image_layer(image, ""), image.width, image.height)}}},
        {"files",
         {{"lightmap.exr", std::string("final lightmap: RGB = irradiance/pi") + (denoiser_ ? ", denoised" : "") +
                               "; layers " + (denoiser_ ? "raw (as baked), " : "") +
                               "direct, indirect, samples, error, covered (1: a surface texel, 0: its dilated copies)" +
                               (image.channels.count("L1x.R") ? ", L1x, L1y, L1z (directional)" : "")},
          {"lightmap.pass-NNNN.exr", "intermediate lightmap snapshots"}}},
    };
    if (prepared_.atlas.pages.count > 1)
        result.manifest["files"]["lightmap.page-N.exr"] = page_files_description("lightmap.exr");
    return result;
}

}  // namespace lf
