#include "outputs.h"

#include "worker_protocol.h"

#include <filesystem>

namespace lf::protocol {

namespace {

std::vector<OutputKind> build_registry() {
    const std::string exr = "image/x-exr", json = "application/json", binary = "application/octet-stream",
                      glb = "model/gltf-binary";
    OutputKind lightmap;
    lightmap.name = "lightmap";
    lightmap.help = "a lightmap of the atlas (irradiance/pi per texel, DESIGN.md \"Units\")";
    lightmap.domain = OutputDomain::Texel;
    lightmap.needs_light = true;
    lightmap.stop_prefix = "";
    lightmap.pass_unit = "one gather per sample point";
    lightmap.lit_scene_slot = "lightmap";
    lightmap.files = {{"lightmap.exr", exr}, {"lightmap.page-N.exr", exr}, {"lightmap.pass-NNNN.exr", exr}};

    OutputKind sh;
    sh.name = "sh";
    sh.help = "per-vertex SH transfer for relighting under any environment";
    sh.domain = OutputDomain::Vertex;
    sh.per_texel_setting = "sh_per_texel";
    sh.stop_prefix = "sh_";
    sh.pass_unit = "64 rays per vertex";
    sh.files = {{"sh_transfer.bin", binary},
                {"sh_transfer.half.bin", binary},
                {"scene.sh.glb", glb},
                {"sh_transfer.pass-NNNN.bin", binary},
                {"sh_transfer.exr", exr},
                {"sh_transfer.page-N.exr", exr},
                {"sh_transfer.pass-NNNN.exr", exr},
                {"env_sh.json", json}};

    OutputKind probes;
    probes.name = "probes";
    probes.help = "light probes: radiance and distance cube maps at points in space";
    probes.domain = OutputDomain::Probe;
    probes.needs_light = true;
    probes.stop_prefix = "probe_";
    probes.pass_unit = "one path per capture texel";
    probes.files = {
        {"probes.json", json}, {"probes.exr", exr}, {"probes.pass-NNNN.json", json}, {"probes.pass-NNNN.exr", exr}};

    OutputKind ao;
    ao.name = "ao";
    ao.help = "ambient occlusion of the atlas (1 in the open, 0 enclosed; glTF's occlusionTexture)";
    ao.domain = OutputDomain::Texel;
    ao.stop_prefix = "ao_";
    ao.pass_unit = "one cosine-weighted ray per sample point";
    ao.lit_scene_slot = "occlusion";
    ao.files = {{"ao.exr", exr}, {"ao.page-N.exr", exr}, {"ao.pass-NNNN.exr", exr}};

    return {lightmap, sh, probes, ao};
}

}  // namespace

const std::vector<OutputKind>& output_registry() {
    static const std::vector<OutputKind> registry = build_registry();
    return registry;
}

const OutputKind* find_output(const std::string& name) {
    for (const OutputKind& o : output_registry())
        if (o.name == name) return &o;
    return nullptr;
}

const std::vector<std::string>& output_names() {
    static const std::vector<std::string> names = [] {
        std::vector<std::string> n;
        for (const OutputKind& o : output_registry()) n.push_back(o.name);
        return n;
    }();
    return names;
}

std::string content_type_of(const std::string& file) {
    const std::string pattern = snapshot_pattern(file), page = page_pattern(file);
    for (const OutputKind& o : output_registry())
        for (const OutputFile& f : o.files)
            if (f.name == file || f.name == pattern || f.name == page) return f.content_type;
    const std::string ext = std::filesystem::path(file).extension().string();
    if (ext == ".exr") return "image/x-exr";
    if (ext == ".png") return "image/png";
    if (ext == ".json") return "application/json";
    if (ext == ".glb") return "model/gltf-binary";
    if (ext == ".gltf") return "model/gltf+json";
    if (ext == ".txt" || ext == ".log") return "text/plain";
    return "application/octet-stream";
}

}  // namespace lf::protocol
