// A baked set of light probes (Umenhoffer & Szirmay-Kalos, "Robust Diffuse
// Final Gathering on the GPU"): per probe, a cube map taken from its
// reference point holding, per texel, the radiance of the surface seen
// through it and that surface's distance, downsampled to M x M per face.
// This is what probes.exr + probes.json hold, and what evaluation reads.
//
// Cube faces, in this order: +X, -X, +Y, -Y, +Z, -Z (OpenGL's cube map
// convention). Within a face, texel (i, j) (column i, row j, row 0 at the
// top) covers face coordinates u in [i/M, (i+1)/M], v in [j/M, (j+1)/M];
// cube_direction(face, u, v) gives the direction through (u, v). The same
// mapping is gi/shaders/probe_cube.glsl's lf_cube_direction (tested equal).
//
// probes.exr (version 2): cells of (M+1) x (M+1) pixels, width 6·(M+1) (the
// faces side by side, in the order above), height (M+1)·N (probe k in rows
// [k·(M+1), (k+1)·(M+1))). In a cell, pixel (i, j) < M holds texel (i, j):
// channels R, G, B (radiance, W/(sr·m²), linear) and Z (distance in metres
// from the probe's position to the surface seen through the texel, the mean
// over the texel's rays; kMissDistance where rays escape the scene); pixel
// (a, b) <= M holds corner (a, b)'s distance in channel C
// (Probe::corner_distance); pixel (i, j) < M also holds, in channel D, the
// distance along texel (i, j)'s centre direction (Probe::centre_distance).
// Invalid probes' rows are 0. Version 2 (read only): no D. Version 1 (read
// only): cells of M x M, no C.
// probes.json: {"format": "lightfarm.probes", "version": 3, "image": "probes.exr",
//   "m", "capture_resolution", "probes": [{"position": [x,y,z], "moved_from" (if moved), "valid", "why",
//   "backface_fraction", "sh9": [[r,g,b] x 9]}], "settings": {…}}.
#pragma once

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace lf {

// Distance stored for a texel whose rays leave the scene: far enough that
// its polygon subtends what the texel's solid angle does, from anywhere nearby.
constexpr float kMissDistance = 1e6f;

struct Probe {
    glm::vec3 position{0.0f};  // the reference point: where the cube maps were taken
    // Where the placement put it, when it was moved away from a surface
    // closer than the clearance (ProbesMethod::kClearance): a grid probe keeps
    // its lattice point for blending and its reference point for its light.
    std::optional<glm::vec3> moved_from;
    bool valid = true;
    std::string why = "kept";         // or why it was dropped: "inside geometry", "far from every surface"
    float backface_fraction = 0.0f;   // of the capture's rays that hit the back of a one-sided surface
    std::vector<glm::vec3> radiance;  // 6·M·M, face-major, rows from the top
    std::vector<float> distance;      // 6·M·M
    // 6·(M+1)²: along each corner of the faces' M x M grids (face f, column
    // a, row b at (f·(M+1) + b)·(M+1) + a; direction cube_direction(f, a/M,
    // b/M)), the distance to the surface the corner's own ray met at capture,
    // kMissDistance where it escaped. Empty in files written before it
    // (evaluation then reads corners from the texels: cube_corner_distances).
    std::vector<float> corner_distance;
    // 6·M·M, in texel order: the distance along each texel's centre
    // direction to the surface its own ray met at capture (kMissDistance where
    // it escaped). With the corners, it tells a texel that sees one flat
    // surface from a chord across an edge (whose corners can lie on one plane
    // too: two on the floor, two on the wall). Empty in files before version 3.
    std::vector<float> centre_distance;
    std::array<glm::vec3, 9> sh9{};  // radiance at the reference point on SH bands 0..2 (index l(l+1)+m), unconvolved
};

struct ProbeSet {
    int m = 0;                   // texels per face side after downsampling
    int capture_resolution = 0;  // R: texels per face side when captured
    std::vector<Probe> probes;
    nlohmann::json settings = nlohmann::json::object();

    size_t texel(int face, int i, int j) const { return (size_t(face) * m + size_t(j)) * m + size_t(i); }
};

// Unit direction through face coordinates (u, v) in [0, 1]² of a cube face (0..5).
glm::vec3 cube_direction(int face, float u, float v);

// Averages an R x R per-face capture down to M x M (R a multiple of M).
// Radiance: the mean over each block of fine texels weighted by their solid
// angles (cube_texel_solid_angle), so that the radiance integrated over a
// coarse texel is the capture's (the corner texels of a face cover less
// solid angle than its centre's: a plain mean moved the irradiance at the
// reference point by -22% to +6% for M = 2 and 4 under the Cornell box's
// small emitter; tests/test_probe_capture.cpp). Distance: the plain mean,
// as the capture's rays are spread evenly over the face coordinates
// (cube_texel_depths reads it so). Misses (kMissDistance) average in as
// misses only when the whole block missed; otherwise the block's distance
// is the mean over its hits, so a texel's polygon corners stay on the
// surfaces it sees.
void downsample_faces(int r, const std::vector<glm::vec3>& radiance, const std::vector<float>& distance, int m,
                      std::vector<glm::vec3>& radiance_out, std::vector<float>& distance_out);

// Writes probes.exr and probes.json into `dir` (atomically); returns their names.
std::vector<std::string> write_probe_set(const std::filesystem::path& dir, const ProbeSet& set,
                                         const std::string& stem = "probes");
// Reads probes.json and the image it names (beside it). Throws std::runtime_error naming the file.
ProbeSet read_probe_set(const std::filesystem::path& probes_json);

}  // namespace lf
