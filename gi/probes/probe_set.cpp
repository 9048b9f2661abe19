#include "probes/probe_set.h"

#include "probes/probe_eval.h"

#include "io/image_files.h"

#include <algorithm>
#include <fstream>
#include <stdexcept>

namespace lf {

glm::vec3 cube_direction(int face, float u, float v) {
    // OpenGL's table "selection of cube map images": s, t in [-1, 1] with t
    // growing down the face (rows from the top).
    const float s = 2.0f * u - 1.0f, t = 2.0f * v - 1.0f;
    glm::vec3 d;
    switch (face) {
    case 0: d = {1.0f, -t, -s}; break;    // +X
    case 1: d = {-1.0f, -t, s}; break;    // -X
    case 2: d = {s, 1.0f, t}; break;      // +Y
    case 3: d = {s, -1.0f, -t}; break;    // -Y
    case 4: d = {s, -t, 1.0f}; break;     // +Z
    default: d = {-s, -t, -1.0f}; break;  // -Z
    }
    return glm::normalize(d);
}

void downsample_faces(int r, const std::vector<glm::vec3>& radiance, const std::vector<float>& distance, int m,
                      std::vector<glm::vec3>& radiance_out, std::vector<float>& distance_out) {
    if (m < 1 || r < m || r % m != 0) throw std::invalid_argument("downsample_faces: R must be a multiple of M");
    const int block = r / m;
    radiance_out.assign(size_t(6) * m * m, glm::vec3(0.0f));
    distance_out.assign(size_t(6) * m * m, 0.0f);
    // Each fine texel's solid angle (the same on every face).
    std::vector<double> solid(size_t(r) * r);
    for (int y = 0; y < r; ++y)
        for (int x = 0; x < r; ++x) solid[size_t(y) * r + x] = cube_texel_solid_angle(r, x, y);
    for (int face = 0; face < 6; ++face)
        for (int j = 0; j < m; ++j)
            for (int i = 0; i < m; ++i) {
                glm::dvec3 l(0.0);
                double omega = 0.0, hit_sum = 0.0;
                int hits = 0;
                for (int y = j * block; y < (j + 1) * block; ++y)
                    for (int x = i * block; x < (i + 1) * block; ++x) {
                        const size_t fine = (size_t(face) * r + size_t(y)) * r + size_t(x);
                        const double w = solid[size_t(y) * r + x];
                        l += glm::dvec3(radiance[fine]) * w;
                        omega += w;
                        if (distance[fine] < kMissDistance) {
                            hit_sum += distance[fine];
                            ++hits;
                        }
                    }
                const size_t coarse = (size_t(face) * m + size_t(j)) * m + size_t(i);
                radiance_out[coarse] = glm::vec3(l / omega);
                distance_out[coarse] = hits > 0 ? float(hit_sum / hits) : kMissDistance;
            }
}

namespace {

nlohmann::json vec3_json(glm::vec3 v) { return {v.x, v.y, v.z}; }

glm::vec3 json_vec3(const nlohmann::json& j, const std::string& what) {
    if (!j.is_array() || j.size() != 3 || !j[0].is_number() || !j[1].is_number() || !j[2].is_number())
        throw std::runtime_error(what + " must be [x, y, z]");
    return {j[0].get<float>(), j[1].get<float>(), j[2].get<float>()};
}

}  // namespace

std::vector<std::string> write_probe_set(const std::filesystem::path& dir, const ProbeSet& set,
                                         const std::string& stem) {
    const int m = set.m, n = int(set.probes.size()), cell = m + 1;
    FloatImage image;
    image.width = 6 * cell;
    image.height = std::max(1, cell * n);
    std::vector<float>* rgb[3] = {&image.channel("R"), &image.channel("G"), &image.channel("B")};
    std::vector<float>& z = image.channel("Z");
    std::vector<float>& c = image.channel("C");
    std::vector<float>& centre = image.channel("D");
    nlohmann::json probes = nlohmann::json::array();
    for (int k = 0; k < n; ++k) {
        const Probe& p = set.probes[size_t(k)];
        nlohmann::json sh9 = nlohmann::json::array();
        for (const glm::vec3& coefficient : p.sh9) sh9.push_back(vec3_json(coefficient));
        probes.push_back({{"position", vec3_json(p.position)},
                          {"valid", p.valid},
                          {"why", p.why},
                          {"backface_fraction", p.backface_fraction},
                          {"sh9", sh9}});
        if (p.moved_from) probes.back()["moved_from"] = vec3_json(*p.moved_from);
        if (!p.valid || p.radiance.size() != size_t(6) * m * m) continue;
        const bool corners = p.corner_distance.size() == size_t(6) * cell * cell;
        const bool centres = p.centre_distance.size() == size_t(6) * m * m;
        for (int face = 0; face < 6; ++face)
            for (int j = 0; j <= m; ++j)
                for (int i = 0; i <= m; ++i) {
                    const size_t to = size_t(k * cell + j) * size_t(image.width) + size_t(face * cell + i);
                    // Without traced corners, misses: the reader falls back to the texels.
                    c[to] = corners ? p.corner_distance[(size_t(face) * cell + j) * cell + i] : kMissDistance;
                    if (i == m || j == m) continue;
                    const size_t from = set.texel(face, i, j);
                    for (int ch = 0; ch < 3; ++ch) (*rgb[ch])[to] = p.radiance[from][ch];
                    z[to] = p.distance[from];
                    centre[to] = centres ? p.centre_distance[from] : 0.0f;  // 0: not traced
                }
    }
    image.number_attributes["lightfarm.probeM"] = m;
    image.string_attributes["lightfarm.layout"] =
        "cells of (M+1)x(M+1): faces +X,-X,+Y,-Y,+Z,-Z side by side, probe k in rows [k*(M+1), (k+1)*(M+1)); pixel "
        "(i,j) < M of a cell: R,G,B radiance, Z distance (m) of texel (i,j), D distance (m) along its centre "
        "direction; pixel (a,b) <= M: C "
        "distance (m) along corner (a,b)";
    const std::string exr = stem + ".exr", json = stem + ".json";
    write_exr(dir / exr, image);
    const nlohmann::json doc = {{"format", "lightfarm.probes"},
                                {"version", 3},
                                {"image", exr},
                                {"m", m},
                                {"capture_resolution", set.capture_resolution},
                                {"probes", probes},
                                {"settings", set.settings}};
    write_file_atomic(dir / json, doc.dump(2) + "\n");
    return {json, exr};
}

ProbeSet read_probe_set(const std::filesystem::path& probes_json) {
    const std::string name = probes_json.filename().string();
    std::ifstream in(probes_json);
    if (!in) throw std::runtime_error(probes_json.string() + ": cannot be read");
    const nlohmann::json doc = nlohmann::json::parse(in, nullptr, false);
    if (!doc.is_object() || doc.value("format", "") != "lightfarm.probes")
        throw std::runtime_error(name + ": not a lightfarm probes file");
    ProbeSet set;
    set.m = doc.value("m", 0);
    set.capture_resolution = doc.value("capture_resolution", 0);
    if (set.m < 1 || set.m > 256) throw std::runtime_error(name + ": m must be 1..256");
    const int version = doc.value("version", 1);
    if (version < 1 || version > 3)
        throw std::runtime_error(name + ": version " + std::to_string(version) + " is not 1, 2 or 3");
    set.settings = doc.value("settings", nlohmann::json::object());
    const FloatImage image = read_exr(probes_json.parent_path() / doc.value("image", "probes.exr"));
    const auto& probes = doc.at("probes");
    const int m = set.m, cell = version >= 2 ? m + 1 : m;
    if (image.width != 6 * cell || image.height < cell * int(probes.size()))
        throw std::runtime_error(name + ": the image's size does not match m and the probe count");
    const std::string image_name = doc.value("image", "probes.exr");
    const auto channel = [&](const std::string& key) -> const std::vector<float>& {
        const auto it = image.channels.find(key);
        if (it == image.channels.end())
            throw std::runtime_error(name + ": " + image_name + " has no channel " + key + " (version " +
                                     std::to_string(version) + " has R, G, B, Z" + (version >= 2 ? ", C" : "") +
                                     (version >= 3 ? ", D" : "") + ")");
        return it->second;
    };
    const std::vector<float>*rgb[3] = {&channel("R"), &channel("G"), &channel("B")}, &z = channel("Z");
    const std::vector<float>* c = version >= 2 ? &channel("C") : nullptr;
    const std::vector<float>* centre = version >= 3 ? &channel("D") : nullptr;
    for (size_t k = 0; k < probes.size(); ++k) {
        const nlohmann::json& j = probes[k];
        Probe p;
        p.position = json_vec3(j.at("position"), name + ": probe " + std::to_string(k) + " position");
        if (j.contains("moved_from"))
            p.moved_from = json_vec3(j["moved_from"], name + ": probe " + std::to_string(k) + " moved_from");
        p.valid = j.value("valid", true);
        p.why = j.value("why", "");
        p.backface_fraction = j.value("backface_fraction", 0.0f);
        if (j.contains("sh9") && j["sh9"].is_array() && j["sh9"].size() == 9)
            for (size_t s = 0; s < 9; ++s) p.sh9[s] = json_vec3(j["sh9"][s], name + ": sh9");
        p.radiance.assign(size_t(6) * m * m, glm::vec3(0.0f));
        p.distance.assign(size_t(6) * m * m, 0.0f);
        if (c) p.corner_distance.assign(size_t(6) * cell * cell, 0.0f);
        if (centre) p.centre_distance.assign(size_t(6) * m * m, 0.0f);
        for (int face = 0; face < 6; ++face)
            for (int jj = 0; jj < cell; ++jj)
                for (int i = 0; i < cell; ++i) {
                    const size_t from = size_t(int(k) * cell + jj) * size_t(image.width) + size_t(face * cell + i);
                    if (c) p.corner_distance[(size_t(face) * cell + jj) * cell + i] = (*c)[from];
                    if (i == m || jj == m) continue;
                    const size_t to = set.texel(face, i, jj);
                    p.radiance[to] = glm::vec3((*rgb[0])[from], (*rgb[1])[from], (*rgb[2])[from]);
                    p.distance[to] = z[from];
                    if (centre) p.centre_distance[to] = (*centre)[from];
                }
        // A probe written without its corners (invalid) reads as one; a
        // centre of 0 was not traced (a set made without them).
        if (c && !p.valid) p.corner_distance.clear();
        if (centre && (!p.valid || std::count(p.centre_distance.begin(), p.centre_distance.end(), 0.0f) > 0))
            p.centre_distance.clear();
        set.probes.push_back(std::move(p));
    }
    return set;
}

}  // namespace lf
