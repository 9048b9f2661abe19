// Evaluation of light probes (gi/probes/probe_set.h): the irradiance / π (the
// lightmap's unit, DESIGN.md) at a point x with normal n, by four estimators
// (issue 11):
//
//   sh9              the probe's SH9 (the environment at the reference point)
//                    convolved with the clamped cosine (Ramamoorthi & Hanrahan
//                    2001: A0 = π, A1 = 2π/3, A2 = π/4) at n, / π. Ignores x:
//                    the paper's first column, exact only at the probe.
//   point_to_point   every texel a point light at probe + distance·direction
//                    (the paper's baseline). Blows up as x nears a wall: kept.
//   polygon_to_point every texel a quadrilateral whose corners lie at the
//                    corner distances (below) along the corner directions,
//                    as its two triangles split along corners 0-2; each
//                    clipped to x's horizon, contribution L_i · F_i with F_i
//                    the signed polygon-to-point form factor (the paper's
//                    eq. 1 and listing), at x or, where x lies just beyond a
//                    texel's polygon that cuts across a room's edge, just
//                    inside it (probe_point_inside). The paper instead takes
//                    L_i · max(F_i, 0) of the unclipped quad
//                    (ProbeEvalOptions::clip_to_horizon = false, to compare).
//   ddgi             Majercik et al. 2019: the probe's cosine-convolved
//                    radiance at n, blended over probes with trilinear ×
//                    backface × Chebyshev-visibility weights from the
//                    mean / mean² distance towards x.
//
// Corner distances. Each corner of the cube grid lies where its own
// direction meets the scene: one ray per corner at capture
// (Probe::corner_distance, probe_corners.comp), so a polygon's corners are on
// the surfaces at any angle to the cube's faces (a floor seen through a side
// face, a slope, a wall edge-on). Where a corner's ray escaped past the edge
// of a surface whose next two corners along a grid line it met, the corner
// goes where its direction meets that surface's plane continued (the two
// corners' line: a grid line's directions span one plane through the probe),
// so an edge texel's polygon lies in its surface's plane, as its hits do
// (an emitter's edge across texels: 46% off 0.36 m from the probe before,
// 9% after, M 8). Otherwise, or for files written before corners were
// traced, the texels around it say, as follows.
// Each texel's (mean) distance is read as the depth z of a
// plane facing the probe across the texel's cube face: z = distance / mean|q|
// over the texel, |q| = sqrt(1 + s² + t²) for face coordinates s, t in
// [-1, 1] (the capture spreads its rays evenly in (s, t)), which is exact for
// a wall perpendicular to the face's axis. A corner of the cube grid, at the
// point P of the cube [-1, 1]³, gets |P| times the mean depth of the texels
// that share it: 4 inside a face, 2 + 2 on a face edge (across the edge, on
// the neighbouring face), 3 at a cube corner. So neighbouring polygons share
// corners and tile the sphere of directions around x without gaps or overlaps
// (a closed room stays closed around x), and in a room whose walls face the
// cube's faces every corner lies on the walls, the room's own corners
// included, at any M. The paper's shader instead reads the corner distance
// with a bilinear texCUBE of the mean distances: that pulls corners inwards
// (a concave room corner at M = 1 to 0.69 of its distance), leaving points
// near walls outside the polygons, where the polygons' form factors cancel;
// the depth reading removes that (measured in tests/test_probes.cpp). The
// virtual light of point_to_point is the same plane's point on the texel's
// centre direction. Texels whose rays all missed (kMissDistance) are left out
// of a corner's mean while any texel around it hit something (the rule
// downsample_faces uses inside a texel); a corner with only misses around it
// stays at kMissDistance.
//
// Grids. Evaluating a ProbeSet blends its valid probes (invalid ones are never
// used): when the probes' positions form a full regular lattice (as a
// --probe-spacing grid does), with the trilinear weights of the lattice cell
// around x (weights of invalid corners dropped, the rest renormalized);
// otherwise (explicit positions, moved probes) with Franke–Little inverse
// distance weights ((R - d)/(R d))² over the 8 nearest valid probes, R the
// distance to the 9th (continuous in x). sh9, point_to_point and
// polygon_to_point blend only the probes that see x (probe_sees: a point
// behind a wall takes no light from the probes on the wall's other side);
// DDGI multiplies the plain weights by its backface and Chebyshev visibility
// factors, as its paper does.
#pragma once

#include "probes/probe_set.h"

#include <glm/glm.hpp>
#include <nlohmann/json.hpp>

#include <array>
#include <filesystem>
#include <vector>

namespace lf {

// The point-to-polygon form factor (differential area at x with unit normal
// n to a polygon): Lambert's formula, the paper's eq. 1 divided by π,
//   F = 1/(2π) Σ_l γ_l · (n · unit(R_l × R_{l+1})),  R_l = corners[l] − x,
// γ_l the angle between R_l and R_{l+1} (atan2(|R_l × R_{l+1}|, R_l · R_{l+1})),
// each edge with its own pair of corners. Orientation: F > 0 when the corners
// wind counter-clockwise about the direction from x towards the polygon
// (right-hand rule about that direction; equivalently counter-clockwise about
// n when projected on the tangent plane and viewed from the tip of n) — the
// cube texels' polygons are built that way as seen from the probe. The other
// winding gives −F. Exact (the projected solid angle / π, i.e. the fraction of
// a Lambertian receiver's irradiance) for any planar polygon entirely above
// x's tangent plane. For a polygon partly below the plane the formula
// integrates the signed cosine, so the part below subtracts; the result is
// returned as is (it can be negative): the paper clamps it at 0 per texel
// polygon (which loses that texel's above-plane part when the sum goes
// negative), and clipped_polygon_to_point_form_factor is the exact value. An edge through x (|R_l × R_{l+1}| = 0)
// contributes 0.
float polygon_to_point_form_factor(glm::vec3 x, glm::vec3 n, const glm::vec3* corners, int count);

// The exact form factor of a planar polygon partly below the tangent plane:
// the polygon clipped to n · (y − x) >= 0 (Sutherland–Hodgman), then the
// formula above. Same orientation rule; count <= 8.
float clipped_polygon_to_point_form_factor(glm::vec3 x, glm::vec3 n, const glm::vec3* corners, int count);

// Exact solid angle of texel (i, j) of an r × r cube face (the same on every face).
double cube_texel_solid_angle(int r, int i, int j);

// SH9 (bands 0..2, real orthonormal basis of gi/sh/sh_basis.h, index
// l(l+1)+m, y up) of an r × r-per-face cube map of radiance (6·r·r, face-major
// as ProbeSet::texel), each texel at its centre direction weighted by its
// exact solid angle. Fills Probe::sh9.
std::array<glm::vec3, 9> project_cube_to_sh9(int r, const std::vector<glm::vec3>& radiance);

// The SH9 radiance convolved with the clamped cosine at unit n, / π.
glm::vec3 sh9_irradiance_over_pi(const std::array<glm::vec3, 9>& sh9, glm::vec3 n);

// Texel depths z = distance / mean|q| (kMissDistance stays), 6·M·M values.
std::vector<float> cube_texel_depths(int m, const std::vector<float>& distance);

// Corner distances of an M × M cube map (the rule in the header comment):
// 6·(M+1)² values, corner (a, b) of face f (a the column 0..M, b the row
// 0..M, at face coordinates (a/M, b/M)) at index (f·(M+1) + b)·(M+1) + a.
std::vector<float> cube_corner_distances(int m, const std::vector<float>& distance);

// The corner distances evaluation uses, in the same order: each corner's own
// ray (Probe::corner_distance) where it met a surface, so that a corner lies
// on the surface its direction meets, at any angle to the faces; where it
// escaped, the plane of the surface beside it continued (the header comment);
// else, or when the file has no corners, cube_corner_distances' value (the
// texels around it: a corner between texels that hit stays at their depth).
std::vector<float> probe_corner_distances(const Probe& probe, int m);

struct ProbeEvaluation {
    glm::vec3 sh9{0.0f};
    glm::vec3 point_to_point{0.0f};
    glm::vec3 polygon_to_point{0.0f};
    glm::vec3 ddgi{0.0f};
};

struct ProbeEvalOptions {
    // polygon_to_point: true = each texel's two triangles clipped to the
    // point's tangent plane, their signed form factors summed (exact for
    // uniform radiance in any room: probe_eval.cpp says why); false = the
    // paper's clamp, max(F, 0) per texel of the unclipped sum (kept to
    // compare: it loses up to half the light 1 cm from two walls).
    bool clip_to_horizon = true;
    // DDGI: x is moved by normal_bias along n before the visibility test
    // (Majercik's self-shadow bias), in metres.
    float ddgi_normal_bias = 0.02f;
    // DDGI: the moments towards x average texel distances with weights
    // max(0, ω·d_i)^power · Ω_i (Majercik's depth lobe, power 50).
    float ddgi_moment_power = 50.0f;
};

// One probe's texels made ready for evaluation (world-space geometry).
struct PreparedProbe {
    struct Texel {
        glm::vec3 radiance{0.0f};
        glm::vec3 direction{0.0f};  // unit, through the texel centre
        glm::vec3 centre{0.0f};     // the virtual light: probe + depth·|q_centre| · direction
        glm::vec3 normal{0.0f};     // of the polygon (cross of its diagonals), towards the probe
        float distance = 0.0f;      // as stored: the mean over the texel's rays
        float solid_angle = 0.0f;   // exact, from the probe
        float area = 0.0f;          // solid_angle · |centre − probe|² / max(cos(normal, −direction), 0.02)
        std::array<glm::vec3, 4> corners{};            // world space, wound as polygon_to_point_form_factor wants
        std::array<glm::vec3, 4> corner_directions{};  // unit
        bool corners_traced = true;  // every corner where its own ray met a surface (Probe::corner_distance)
        // Its four corners traced and on one plane: the texel sees one flat
        // surface, and that surface is the polygon (probe_sees is exact there).
        bool planar = false;
        // Its corners on two surfaces, neither enclosing the other (a depth
        // jump, an outer edge), the nearer brighter than the farther (an
        // emitter's edge; split_bridges says why): its polygon, the bridge
        // from the nearer surface to the farther, carries the farther one's
        // radiance, and a polygon on the nearer one's plane across the texel
        // the rest.
        bool split = false;
        glm::vec3 bridge_radiance{0.0f};
        std::array<glm::vec3, 4> near_corners{};  // world space, wound as corners
    };
    glm::vec3 position{0.0f};
    int m = 0;
    std::array<glm::vec3, 9> sh9{};
    std::vector<Texel> texels;  // 6·M·M, ProbeSet::texel order
};

PreparedProbe prepare_probe(const Probe& probe, int m);

// One probe's estimators (irradiance / π).
glm::vec3 probe_sh9(const PreparedProbe& p, glm::vec3 n);
glm::vec3 probe_point_to_point(const PreparedProbe& p, glm::vec3 x, glm::vec3 n);
// x, or where x lies just beyond the polygon the probe sees towards it (by
// at most the polygon's longer diagonal: between a polygon that cuts
// across a room's edge and the edge), the point just inside that polygon on
// the line from the probe to x (probe_eval.cpp says why).
glm::vec3 probe_point_inside(const PreparedProbe& p, glm::vec3 x);
// Whether the probe sees x: x is no farther along the line from the probe
// than the surface the probe's distances put there (probe_eval.cpp says how,
// texel by texel). A point behind a wall, a partition or the floor is not
// seen; a point on a surface the probe sees is.
bool probe_sees(const PreparedProbe& p, glm::vec3 x);
glm::vec3 probe_polygon_to_point(const PreparedProbe& p, glm::vec3 x, glm::vec3 n, bool clip_to_horizon = true);
// The probe's cosine-convolved radiance at n, / π: the piecewise-constant
// texel radiance integrated exactly against max(0, n·ω) (each texel's
// spherical quad clipped to the hemisphere) — DDGI's irradiance texel.
glm::vec3 probe_convolved_irradiance(const PreparedProbe& p, glm::vec3 n);
// DDGI's distance moments (mean, mean²) towards unit direction w.
glm::vec2 probe_distance_moments(const PreparedProbe& p, glm::vec3 w, float power = 50.0f);
// DDGI's weight of probe p for x (before the trilinear / inverse-distance weight):
// backface ((1 + cos)/2)² + 0.2, times max(0.05, Chebyshev³), small weights crushed.
float ddgi_probe_weight(const PreparedProbe& p, glm::vec3 x, glm::vec3 n, const ProbeEvalOptions& options = {});
ProbeEvaluation evaluate_probe(const PreparedProbe& p, glm::vec3 x, glm::vec3 n, const ProbeEvalOptions& options = {});

// A whole set, prepared once, evaluated at many points.
class ProbeEvaluator {
public:
    explicit ProbeEvaluator(const ProbeSet& set, ProbeEvalOptions options = {});
    ProbeEvaluation evaluate(glm::vec3 x, glm::vec3 n) const;
    // The plain blend weights at x: (index into the set's probes, weight), summing to 1.
    std::vector<std::pair<int, float>> weights(glm::vec3 x) const;
    // The same blend over the probes that see x (probe_sees): the lattice
    // cell's corners that see it, else the nearest probes that see it. Empty
    // when no probe sees x: then nothing is known of its light, and sh9,
    // point_to_point and polygon_to_point evaluate to 0 there.
    std::vector<std::pair<int, float>> visible_weights(glm::vec3 x) const;
    bool is_grid() const { return grid_; }
    size_t valid_probes() const { return valid_count_; }

private:
    // The blend over the valid probes for which `usable` holds.
    template <class Usable>
    std::vector<std::pair<int, float>> blend(glm::vec3 x, const Usable& usable) const;
    ProbeEvalOptions options_;
    std::vector<PreparedProbe> prepared_;  // one per probe of the set (empty for invalid ones)
    std::vector<bool> valid_;
    size_t valid_count_ = 0;
    bool grid_ = false;
    std::array<std::vector<float>, 3> axis_;  // lattice coordinates when grid_
    std::vector<int> lattice_;                // lattice index -> probe index
};

// All four at (x, n) from the set's valid probes (blended as above). Throws
// std::invalid_argument when the set has no valid probe.
ProbeEvaluation evaluate(const ProbeSet& set, glm::vec3 x, glm::vec3 n, const ProbeEvalOptions& options = {});

// A shading point: where a renderer asks the probes for light, and its normal (unit).
struct ShadingPoint {
    glm::vec3 position;
    glm::vec3 normal;
};

// `lightfarm probe-eval`'s points: a JSON file of [{"position": [x, y, z],
// "normal": [x, y, z]}, ...], normals normalized. Throws std::runtime_error
// naming the file and the point for an unreadable file, a missing or
// non-finite vector, or a zero normal.
std::vector<ShadingPoint> read_shading_points(const std::filesystem::path& points_json);

// Every estimator at each point, as `lightfarm probe-eval` prints it:
// {"points": [{"sh9": [r, g, b], "point_to_point": …, "polygon_to_point": …,
// "ddgi": …}, …]}. Throws as ProbeEvaluator does.
nlohmann::json evaluate_at_points(const ProbeSet& set, const std::vector<ShadingPoint>& points);

// The SSBO gi/shaders/probe_eval.glsl reads: per probe, 6·M·M vec4 texels
// (radiance RGB, distance) in ProbeSet::texel order, then the 6·(M+1)² corner
// distances of probe_corner_distances packed four to a vec4 (negated where
// the corner's own ray met no surface: Texel::corners_traced), then the
// 6·M·M centre distances (Probe::centre_distance, 0 where the set has none)
// packed four to a vec4, then per texel two vec4: (the bridge's radiance, 1)
// and the nearer plane's four corner distances for a split texel
// (Texel::split; zero otherwise), then the 9 SH9 (their w: the reference
// point's x, y, z, then 0)
// coefficients (RGB); probe k starts at vec4 k · probe_buffer_stride(M).
// Invalid probes' blocks are zero.
size_t probe_buffer_stride(int m);
std::vector<glm::vec4> pack_probe_buffer(const ProbeSet& set);

}  // namespace lf
