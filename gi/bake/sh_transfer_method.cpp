#include "bake/sh_transfer_method.h"

#include "bake/atlas_files.h"
#include "bake/bake_job.h"

#include "atlas/atlas.h"
#include "atlas/lightmapped_gltf.h"
#include "io/image_files.h"
#include "sh/environment.h"
#include "sh/sh_glb.h"
#include "sh/shading.h"
#include "sh/transfer_file.h"
#include "trace/tracer.h"

#include <memory>
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
        for (int g = 0; g < 4; ++g)
            groups[size_t(g)][pixel] = glm::vec4(mean[4 * g], mean[4 * g + 1], mean[4 * g + 2], mean[4 * g + 3]);
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

ShSettings ShSettings::from(const protocol::OutputSettings& o) {
    ShSettings sh;
    sh.bands = o.integer_or_auto("sh_bands");
    sh.bounces = o.integer("sh_bounces");
    sh.window = o.choice("sh_window");
    sh.occluders = o.values.at("sh_occluders").get<std::vector<int>>();
    sh.receivers = o.values.at("sh_receivers").get<std::vector<int>>();
    sh.per_texel = o.flag("sh_per_texel");
    return sh;
}

namespace {

ShTransferSettings transfer_settings(const ShSettings& sh, uint32_t seed) {
    ShTransferSettings t;
    t.bounces = sh.bounces;
    t.seed = seed;
    t.occluder_meshes = sh.occluders;
    t.receiver_meshes = sh.receivers;
    return t;
}

// Occluder and receiver sets name glTF meshes: every one must be drawn.
void check_mesh_sets(const PreparedScene& prepared, const ShSettings& sh) {
    std::set<int> meshes;
    for (const PrimitiveInstance& i : prepared.scene.instances) meshes.insert(i.mesh);
    for (const auto& [field, list] :
         {std::pair{"sh.sh_occluders", &sh.occluders}, std::pair{"sh.sh_receivers", &sh.receivers}})
        for (int m : *list)
            if (!meshes.count(m))
                throw BakeInputError(std::string(field) + ": mesh " + std::to_string(m) + " is not drawn by " +
                                     prepared.file.filename().string() + " (it has " + std::to_string(meshes.size()) +
                                     " meshes)");
}

}  // namespace

ShTransferMethod::ShTransferMethod(const PreparedScene& prepared, const protocol::BakeSettings& settings)
    : prepared_(prepared),
      settings_(ShSettings::from(*settings.output("sh"))),
      transfer_(transfer_settings(settings_, settings.seed)),
      stop_(stop_rule_from(settings.output("sh")->stop())),
      environment_(prepared.environment),
      window_(parse_sh_window(settings_.window)),
      subsamples_(settings.atlas.subsamples),
      uniform_light_(settings.env.sky.has_value()) {
    check_mesh_sets(prepared, settings_);
    // Per texel: the atlas's texel sample points are extra receivers of the same baker.
    if (settings_.per_texel)
        texel_receivers_ = sh_texel_receivers(*prepared.atlas_scene, prepared.texels, transfer_.receiver_meshes);
    baker_ = std::make_unique<ShTransferBaker>(prepared.scene, *prepared.tracer, transfer_, texel_receivers_.points);

    const protocol::EnvironmentSetting& env = settings.env;
    settings_json_ = {
        {"method", "sh_transfer"},
        {"bands", settings_.bands ? nlohmann::json(*settings_.bands) : nlohmann::json("auto")},
        {"auto_bands_error", kAutoBandsError},
        {"bounces", transfer_.bounces},
        {"samples_per_pass", transfer_.samples_per_pass},
        {"occluder_meshes", transfer_.occluder_meshes},
        {"receiver_meshes", transfer_.receiver_meshes},
        {"environment", env.sky ? nlohmann::json(*env.sky) : nlohmann::json(env.map_file)},
        {"window", to_string(window_)},
        {"seed", transfer_.seed},
        {"max_passes", stop_.max_passes},
        {"target_error", stop_.target_error},
        {"time_limit", stop_.time_limit},
        {"per_texel", settings_.per_texel},
    };
    if (settings_.per_texel) {
        settings_json_["per_texel_atlas"] = atlas_json(prepared.atlas);
        settings_json_["per_texel_subsamples"] = settings.atlas.subsamples;
    }
}

ShTransferMethod::~ShTransferMethod() = default;

PassStats ShTransferMethod::step() { return baker_->step(); }

nlohmann::json ShTransferMethod::description() const {
    nlohmann::json d = {{"vertices", prepared_.scene.positions.size()},
                        {"unique_vertices", baker_->unique_vertices()},
                        {"receiver_vertices", baker_->receiver_vertices()},
                        {"settings", settings_json_}};
    if (settings_.per_texel) {
        d["texels"] = prepared_.texels.covered_count();
        d["texel_points"] = texel_receivers_.points.size();
    }
    return d;
}

uint64_t ShTransferMethod::rays_per_pass() const { return baker_->rays_per_pass(); }

FloatImage ShTransferMethod::texel_image(const ShVertexTransfer& t, int bands, const PassStats& s) const {
    FloatImage image = sh_texel_image(prepared_.texels, texel_receivers_, t.point_coefficients, bands);
    image.string_attributes["lightfarm.renderer"] = prepared_.gpu->info().renderer;
    image.string_attributes["lightfarm.settings"] = settings_json_.dump();
    image.number_attributes["lightfarm.pass"] = s.pass;
    image.number_attributes["lightfarm.bounces"] = transfer_.bounces;
    image.number_attributes["lightfarm.samples_per_point"] = double(s.pass) * double(transfer_.samples_per_pass);
    return image;
}

SnapshotWrite ShTransferMethod::snapshot(const fs::path& dir, const PassStats& stats) {
    auto t = std::make_shared<const ShVertexTransfer>(baker_->snapshot());
    return [this, dir, t, stats] {
        const int bands = settings_.bands.value_or(kShMaxBands);
        const std::string name = snapshot_file_name("sh_transfer", stats.pass, "bin");
        write_sh_transfer(dir / name, transfer_by_primitive(prepared_.scene, t->coefficients, bands, transfer_.bounces),
                          ShEncoding::Float32);
        std::vector<std::string> files = {name};
        if (settings_.per_texel) {
            const std::string exr = snapshot_file_name("sh_transfer", stats.pass, "exr");
            write_exr(dir / exr, texel_image(*t, bands, stats));
            files.push_back(exr);
        }
        return files;
    };
}

// Why the transfer has the bands it has (manifest.json's sh.bands_why):
// auto chooses under the job's light, and a uniform sky (or none) has no
// direction, so one band shades it exactly and auto keeps one, useless for
// relighting under another light: said, with what to do.
std::string ShTransferMethod::bands_why(int bands) const {
    if (settings_.bands) return "as asked (sh_bands " + std::to_string(*settings_.bands) + ")";
    std::string why = "auto: the fewest bands whose shading is within " +
                      std::to_string(int(std::lround(kAutoBandsError * 100))) + "% of 4 bands' under the job's light";
    if (uniform_light_ && bands == 1)
        why +=
            "; a uniform sky has no direction, so one band shades it exactly: to relight under other "
            "environments, give sh_bands 4 (--sh-bands 4) or bake with the environment map you will use";
    return why;
}

MethodResult ShTransferMethod::finish(const fs::path& dir, const PassStats& stats) {
    const Scene& scene = prepared_.scene;
    const ShVertexTransfer transfer = baker_->snapshot();
    // Bands: as asked, or the fewest that shade within kAutoBandsError of 4
    // under the environment (a uniform sky without one).
    const EnvironmentSh band_light = project_environment(environment_ ? *environment_ : uniform_sky());
    nlohmann::json band_errors = nlohmann::json::object();
    for (int b = 1; b <= kShMaxBands; ++b)
        band_errors[std::to_string(b)] = band_truncation_error(transfer.coefficients, band_light, b);
    const int bands =
        settings_.bands ? *settings_.bands : choose_band_count(transfer.coefficients, band_light, kAutoBandsError);

    MethodResult result;
    nlohmann::json files = nlohmann::json::object();
    const ShTransferFile file = transfer_by_primitive(scene, transfer.coefficients, bands, transfer_.bounces);
    const std::string exact_bytes = encode_sh_transfer(file, ShEncoding::Float32);
    const std::string half_bytes = encode_sh_transfer(file, ShEncoding::Float16);
    write_file_atomic(dir / "sh_transfer.bin", exact_bytes);
    write_file_atomic(dir / "sh_transfer.half.bin", half_bytes);
    write_sh_glb(prepared_.file, scene, transfer.coefficients, bands, dir / "scene.sh.glb");
    result.files = {"sh_transfer.bin", "sh_transfer.half.bin", "scene.sh.glb"};
    files["sh_transfer.bin"] = "per-vertex SH transfer, float32 (format: gi/sh/transfer_file.h)";
    files["sh_transfer.half.bin"] = "per-vertex SH transfer, float16";
    files["scene.sh.glb"] = "the input scene with _SH_TRANSFER_k VEC4 vertex attributes";
    files["sh_transfer.pass-NNNN.bin"] = "intermediate SH transfer snapshots (float32)";

    nlohmann::json per_texel = false;
    if (settings_.per_texel) {
        for (const std::string& file :
             write_atlas_exr(dir, "sh_transfer.exr", texel_image(transfer, bands, stats), prepared_.atlas.pages))
            result.files.push_back(file);
        if (prepared_.atlas.pages.count > 1)
            files["sh_transfer.page-N.exr"] = page_files_description("sh_transfer.exr");
        files["sh_transfer.exr"] =
            "per-texel SH transfer in the lightmap atlas: channels sh.0 … sh.{bands²-1} "
            "(coefficient l(l+1)+m), coverage; dilated past chart borders";
        files["sh_transfer.pass-NNNN.exr"] = "intermediate per-texel SH transfer snapshots";
        nlohmann::json channels = nlohmann::json::array();
        for (int c = 0; c < bands * bands; ++c) channels.push_back("sh." + std::to_string(c));
        channels.push_back("coverage");
        per_texel = {{"file", "sh_transfer.exr"},
                     {"atlas", atlas_json(prepared_.atlas)},
                     {"subsamples_per_texel", subsamples_ * subsamples_},
                     {"covered_texels", prepared_.texels.covered_count()},
                     {"sample_points", prepared_.texels.samples.size()},
                     {"traced_points", texel_receivers_.points.size()},
                     {"channels", channels}};
    }
    if (environment_) {
        const EnvironmentSh sh = project_environment(*environment_, window_, bands);
        write_file_atomic(dir / "env_sh.json", to_json(sh).dump(2) + "\n");
        result.files.push_back("env_sh.json");
        files["env_sh.json"] = "the environment's SH coefficients (16 RGB), with its window";
    }
    result.manifest = {
        {"settings", settings_json_},
        {"result", protocol::to_json(stats)},
        {"bands", bands},
        {"bands_why", bands_why(bands)},
        {"band_errors", {{"light", band_light.source}, {"relative_rms_vs_4_bands", band_errors}}},
        {"samples_per_vertex", baker_->samples_per_vertex()},
        {"vertices", scene.positions.size()},
        {"unique_vertices", baker_->unique_vertices()},
        {"receiver_vertices", baker_->receiver_vertices()},
        {"per_texel", per_texel},
        {"compact",
         {{"file", "sh_transfer.half.bin"},
          {"encoding", "float16"},
          {"bytes", half_bytes.size()},
          {"float32_bytes", exact_bytes.size()},
          {"error", compact_error(file, decode_sh_transfer(half_bytes, "sh_transfer.half.bin"))}}},
        {"files", files},
    };
    return result;
}

}  // namespace lf
