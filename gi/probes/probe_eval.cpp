#include "probes/probe_eval.h"

#include "sh/sh_basis.h"
#include "util/math.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <stdexcept>

namespace lf {

namespace {

using glm::dvec3;

// Lambert's sum over the edges of a polygon given by its corners relative to x.
double lambert_sum(const dvec3* r, int count, dvec3 n) {
    double sum = 0.0;
    for (int l = 0; l < count; ++l) {
        const dvec3 a = r[l], b = r[(l + 1) % count];
        const dvec3 c = glm::cross(a, b);
        const double len = glm::length(c);
        // An edge through x (or a zero-length one) has no direction to project.
        if (!(len > 1e-15 * glm::length(a) * glm::length(b))) continue;
        sum += std::atan2(len, glm::dot(a, b)) * glm::dot(c, n) / len;
    }
    return sum / (2.0 * kPi);
}

// Clips the polygon r (relative to x) to n · r >= 0; returns the corner count.
int clip_to_plane(const dvec3* r, int count, dvec3 n, dvec3* out) {
    int k = 0;
    for (int l = 0; l < count; ++l) {
        const dvec3 a = r[l], b = r[(l + 1) % count];
        const double ha = glm::dot(n, a), hb = glm::dot(n, b);
        if (ha >= 0.0) out[k++] = a;
        if ((ha >= 0.0) != (hb >= 0.0)) out[k++] = a + (b - a) * (ha / (ha - hb));
    }
    return k;
}

double clipped_sum(const dvec3* r, int count, dvec3 n) {
    dvec3 clipped[2 * 8 + 2];
    const int k = clip_to_plane(r, count, n, clipped);
    return k >= 3 ? lambert_sum(clipped, k, n) : 0.0;
}

// Face coordinates (u, v) of a point on the cube [-1, 1]³ lying on `face`
// (the inverse of cube_direction's table).
glm::dvec2 cube_face_uv(int face, dvec3 p) {
    double s, t;
    switch (face) {
    case 0:
        s = -p.z / p.x;
        t = -p.y / p.x;
        break;
    case 1:
        s = p.z / -p.x;
        t = -p.y / -p.x;
        break;
    case 2:
        s = p.x / p.y;
        t = p.z / p.y;
        break;
    case 3:
        s = p.x / -p.y;
        t = -p.z / -p.y;
        break;
    case 4:
        s = p.x / p.z;
        t = -p.y / p.z;
        break;
    default:
        s = -p.x / -p.z;
        t = -p.y / -p.z;
        break;
    }
    return {(s + 1.0) / 2.0, (t + 1.0) / 2.0};
}

bool on_face(int face, dvec3 p) {
    const int axis = face / 2;
    const double sign = face % 2 == 0 ? 1.0 : -1.0;
    return p[axis] * sign > 1.0 - 1e-6;
}

double area_term(double x, double y) { return std::atan2(x * y, std::sqrt(x * x + y * y + 1.0)); }

}  // namespace

float polygon_to_point_form_factor(glm::vec3 x, glm::vec3 n, const glm::vec3* corners, int count) {
    if (count < 3 || count > 64) throw std::invalid_argument("polygon_to_point_form_factor: 3..64 corners");
    dvec3 r[64];
    for (int l = 0; l < count; ++l) r[l] = dvec3(corners[l]) - dvec3(x);
    return float(lambert_sum(r, count, dvec3(n)));
}

float clipped_polygon_to_point_form_factor(glm::vec3 x, glm::vec3 n, const glm::vec3* corners, int count) {
    if (count < 3 || count > 8) throw std::invalid_argument("clipped_polygon_to_point_form_factor: 3..8 corners");
    dvec3 r[8];
    for (int l = 0; l < count; ++l) r[l] = dvec3(corners[l]) - dvec3(x);
    return float(clipped_sum(r, count, dvec3(n)));
}

double cube_texel_solid_angle(int r, int i, int j) {
    // The solid angle of the face-plane rectangle [0, x] × [0, y] at unit
    // distance is atan(xy / sqrt(x² + y² + 1)); a texel by inclusion-exclusion.
    const double x0 = 2.0 * i / r - 1.0, x1 = 2.0 * (i + 1) / r - 1.0;
    const double y0 = 2.0 * j / r - 1.0, y1 = 2.0 * (j + 1) / r - 1.0;
    return area_term(x0, y0) - area_term(x0, y1) - area_term(x1, y0) + area_term(x1, y1);
}

std::array<glm::vec3, 9> project_cube_to_sh9(int r, const std::vector<glm::vec3>& radiance) {
    if (r < 1 || radiance.size() != size_t(6) * r * r)
        throw std::invalid_argument("project_cube_to_sh9: radiance must hold 6·r·r texels");
    std::vector<double> solid(size_t(r) * r);
    for (int j = 0; j < r; ++j)
        for (int i = 0; i < r; ++i) solid[size_t(j) * r + i] = cube_texel_solid_angle(r, i, j);
    std::array<dvec3, 9> sum{};
    for (int face = 0; face < 6; ++face)
        for (int j = 0; j < r; ++j)
            for (int i = 0; i < r; ++i) {
                const glm::vec3 d = cube_direction(face, (i + 0.5f) / r, (j + 0.5f) / r);
                const ShCoefficients y = sh_evaluate(d);
                const dvec3 l = dvec3(radiance[(size_t(face) * r + j) * r + i]) * solid[size_t(j) * r + i];
                for (int c = 0; c < 9; ++c) sum[c] += l * double(y[c]);
            }
    std::array<glm::vec3, 9> out;
    for (int c = 0; c < 9; ++c) out[c] = glm::vec3(sum[c]);
    return out;
}

glm::vec3 sh9_irradiance_over_pi(const std::array<glm::vec3, 9>& sh9, glm::vec3 n) {
    // Ramamoorthi & Hanrahan's A_l / π: 1, 2/3, 1/4.
    static constexpr float kBand[9] = {1.0f, 2.0f / 3, 2.0f / 3, 2.0f / 3, 0.25f, 0.25f, 0.25f, 0.25f, 0.25f};
    const ShCoefficients y = sh_evaluate(glm::normalize(n));
    glm::vec3 e(0.0f);
    for (int c = 0; c < 9; ++c) e += sh9[c] * (kBand[c] * y[c]);
    return e;
}

double texel_mean_stretch(int m, int i, int j) {
    // The mean of |q| = sqrt(1 + s² + t²) over the texel's square in face
    // coordinates (the capture's rays are spread evenly in (s, t)): a wall at
    // depth z along the face axis is seen at distances z·|q|.
    constexpr int kSteps = 16;
    double sum = 0.0;
    for (int b = 0; b < kSteps; ++b)
        for (int a = 0; a < kSteps; ++a) {
            const double s = 2.0 * (i + (a + 0.5) / kSteps) / m - 1.0, t = 2.0 * (j + (b + 0.5) / kSteps) / m - 1.0;
            sum += std::sqrt(1.0 + s * s + t * t);
        }
    return sum / (kSteps * kSteps);
}

std::vector<float> cube_texel_depths(int m, const std::vector<float>& distance) {
    if (m < 1 || distance.size() != size_t(6) * m * m)
        throw std::invalid_argument("cube_texel_depths: distance must hold 6·M·M texels");
    std::vector<double> stretch(size_t(m) * m);
    for (int j = 0; j < m; ++j)
        for (int i = 0; i < m; ++i) stretch[size_t(j) * m + i] = texel_mean_stretch(m, i, j);
    std::vector<float> depth(distance.size());
    for (int face = 0; face < 6; ++face)
        for (int j = 0; j < m; ++j)
            for (int i = 0; i < m; ++i) {
                const size_t k = (size_t(face) * m + j) * m + i;
                depth[k] =
                    distance[k] < kMissDistance ? float(distance[k] / stretch[size_t(j) * m + i]) : kMissDistance;
            }
    return depth;
}

std::vector<float> cube_corner_distances(int m, const std::vector<float>& distance) {
    const std::vector<float> depth = cube_texel_depths(m, distance);
    const int side = m + 1;
    std::vector<float> out(size_t(6) * side * side, kMissDistance);
    for (int face = 0; face < 6; ++face)
        for (int b = 0; b <= m; ++b)
            for (int a = 0; a <= m; ++a) {
                const dvec3 d(cube_direction(face, float(a) / m, float(b) / m));
                // The corner's point on the cube [-1, 1]³: |p| is the distance
                // along the corner direction to depth 1 on every face it lies on.
                const dvec3 p = d / std::max({std::abs(d.x), std::abs(d.y), std::abs(d.z)});
                double sum = 0.0;
                int hits = 0;
                for (int f = 0; f < 6; ++f) {
                    if (!on_face(f, p)) continue;
                    const glm::dvec2 uv = cube_face_uv(f, p);
                    const int ca = int(std::lround(uv.x * m)), cb = int(std::lround(uv.y * m));
                    for (int j = cb - 1; j <= cb; ++j)
                        for (int i = ca - 1; i <= ca; ++i) {
                            if (i < 0 || j < 0 || i >= m || j >= m) continue;
                            const float z = depth[(size_t(f) * m + j) * m + i];
                            if (z < kMissDistance) {
                                sum += z;
                                ++hits;
                            }
                        }
                }
                if (hits > 0) out[(size_t(face) * side + b) * side + a] = float(glm::length(p) * sum / hits);
            }
    return out;
}

namespace {

// Where the ray along `d` meets the line through p and q (all three in one
// plane through the probe: a grid line's directions span one), or 0 when it
// does not ahead of the probe.
double ray_meets_line(dvec3 d, dvec3 p, dvec3 q) {
    const dvec3 u = p - q, across = glm::cross(d, u);
    const double along = glm::dot(across, across);
    if (along <= 1e-24 * glm::dot(u, u)) return 0.0;
    const double t = glm::dot(glm::cross(p, u), across) / along;  // d·t = p + u·s
    return t > 0.0 ? t : 0.0;
}

}  // namespace

std::vector<float> probe_corner_distances(const Probe& probe, int m) {
    std::vector<float> corners = cube_corner_distances(m, probe.distance);
    if (probe.corner_distance.size() != corners.size()) return corners;
    const int side = m + 1;
    const auto at = [&](int face, int a, int b) { return (size_t(face) * side + size_t(b)) * side + size_t(a); };
    const auto point = [&](int face, int a, int b) {
        return dvec3(cube_direction(face, float(a) / m, float(b) / m)) * double(probe.corner_distance[at(face, a, b)]);
    };
    const auto hit = [&](int face, int a, int b) {
        return a >= 0 && b >= 0 && a <= m && b <= m && probe.corner_distance[at(face, a, b)] < kMissDistance;
    };
    for (int face = 0; face < 6; ++face)
        for (int b = 0; b <= m; ++b)
            for (int a = 0; a <= m; ++a) {
                const size_t c = at(face, a, b);
                if (probe.corner_distance[c] < kMissDistance) {
                    corners[c] = probe.corner_distance[c];
                    continue;
                }
                // Its ray escaped past the edge of a surface the corners
                // beside it met: the surface's plane, continued along the
                // grid line from the two nearest corners on it, where the
                // corner's direction meets it (so the edge texel's polygon
                // lies in the surface's plane, as its hits do); else, the
                // texels around it (cube_corner_distances).
                const dvec3 d(cube_direction(face, float(a) / m, float(b) / m));
                double sum = 0.0;
                int found = 0;
                for (const auto& [da, db] : {std::pair{1, 0}, std::pair{-1, 0}, std::pair{0, 1}, std::pair{0, -1}}) {
                    if (!hit(face, a + da, b + db) || !hit(face, a + 2 * da, b + 2 * db)) continue;
                    const double t =
                        ray_meets_line(d, point(face, a + da, b + db), point(face, a + 2 * da, b + 2 * db));
                    if (t > 0.0 && t < kMissDistance) {
                        sum += t;
                        ++found;
                    }
                }
                if (found > 0) corners[c] = float(sum / found);
            }
    return corners;
}

namespace {

// A texel's corners lie on one plane when each is within a hair of the
// plane through the other three: kFlat of its distance from the probe (the
// corner rays' float rounding is ~1e-6 of it; a room's edge across a texel
// puts a corner 10⁻² to 10⁻¹ of it off).
constexpr double kFlat = 1e-4;

// The corners of a texel, and where traced the point its centre ray met,
// on one plane (each within kFlat of its distance of the plane through the
// others): the texel sees one flat surface. Four corners alone can be
// coplanar across a straight edge (two on the floor, two on the wall); the
// centre's point is then on the floor or the wall, off their plane.
bool texel_is_flat(const std::array<glm::vec3, 4>& corners, glm::vec3 probe, const float* centre_distance,
                   glm::vec3 centre_direction) {
    dvec3 c[4];
    for (int k = 0; k < 4; ++k) c[k] = dvec3(corners[k]) - dvec3(probe);
    for (int k = 0; k < 4; ++k) {
        const dvec3 a = c[(k + 1) % 4], b = c[(k + 2) % 4], d = c[(k + 3) % 4];
        const dvec3 normal = glm::cross(b - a, d - a);
        const double len = glm::length(normal);
        if (!(len > 0.0)) return false;
        if (std::abs(glm::dot(normal / len, c[k] - a)) > kFlat * glm::length(c[k])) return false;
    }
    if (!centre_distance) return true;  // a file without centres: the corners alone
    if (!(*centre_distance < kMissDistance)) return false;
    const dvec3 normal = glm::normalize(glm::cross(c[2] - c[0], c[3] - c[1]));
    const dvec3 centre = dvec3(centre_direction) * double(*centre_distance);
    return std::abs(glm::dot(normal, centre - c[0])) <= kFlat * double(*centre_distance);
}

}  // namespace

namespace {
void split_bridges(PreparedProbe& p);
}  // namespace

PreparedProbe prepare_probe(const Probe& probe, int m) {
    const size_t texels = size_t(6) * m * m;
    if (m < 1 || probe.radiance.size() != texels || probe.distance.size() != texels)
        throw std::invalid_argument("prepare_probe: the probe's faces must hold 6·M·M texels");
    PreparedProbe p;
    p.position = probe.position;
    p.m = m;
    p.sh9 = probe.sh9;
    p.texels.resize(texels);
    const std::vector<float> corner = probe_corner_distances(probe, m);
    const std::vector<float> depth = cube_texel_depths(m, probe.distance);
    const int side = m + 1;
    for (int face = 0; face < 6; ++face)
        for (int j = 0; j < m; ++j)
            for (int i = 0; i < m; ++i) {
                const size_t k = (size_t(face) * m + j) * m + i;
                PreparedProbe::Texel& t = p.texels[k];
                t.radiance = probe.radiance[k];
                t.distance = probe.distance[k];
                t.direction = cube_direction(face, (i + 0.5f) / m, (j + 0.5f) / m);
                // The virtual light: on the texel's plane (depth) along its centre direction.
                const float s = 2.0f * (i + 0.5f) / m - 1.0f, tc = 2.0f * (j + 0.5f) / m - 1.0f;
                const float centre_distance =
                    depth[k] < kMissDistance ? depth[k] * std::sqrt(1.0f + s * s + tc * tc) : kMissDistance;
                t.centre = p.position + centre_distance * t.direction;
                t.solid_angle = float(cube_texel_solid_angle(m, i, j));
                // Counter-clockwise about the outward direction: cube_direction's
                // (∂/∂u × ∂/∂v) points inward on every face, so (u, v) corners go
                // (i, j), (i, j+1), (i+1, j+1), (i+1, j).
                const int ca[4] = {i, i, i + 1, i + 1}, cb[4] = {j, j + 1, j + 1, j};
                for (int c = 0; c < 4; ++c) {
                    const glm::vec3 d = cube_direction(face, float(ca[c]) / m, float(cb[c]) / m);
                    t.corner_directions[c] = d;
                    const size_t at = (size_t(face) * side + cb[c]) * side + ca[c];
                    t.corners[c] = p.position + corner[at] * d;
                    t.corners_traced = t.corners_traced && at < probe.corner_distance.size() &&
                                       probe.corner_distance[at] < kMissDistance;
                }
                glm::vec3 normal = glm::cross(t.corners[2] - t.corners[0], t.corners[3] - t.corners[1]);
                const float len = glm::length(normal);
                normal = len > 0.0f && std::isfinite(len) ? normal / len : -t.direction;
                if (glm::dot(normal, -t.direction) < 0.0f) normal = -normal;
                t.normal = normal;
                const float* centre = probe.centre_distance.size() == texels ? &probe.centre_distance[k] : nullptr;
                t.planar = t.corners_traced && texel_is_flat(t.corners, p.position, centre, t.direction);
                // The surface seen through the texel: its area from the solid
                // angle and distance, tilted by the polygon's normal (floored so
                // that a grazing polygon does not make it unbounded).
                const float facing = std::max(glm::dot(normal, -t.direction), 0.02f);
                t.area = t.solid_angle * centre_distance * centre_distance / facing;
            }
    split_bridges(p);
    return p;
}

glm::vec3 probe_sh9(const PreparedProbe& p, glm::vec3 n) { return sh9_irradiance_over_pi(p.sh9, n); }

glm::vec3 probe_point_to_point(const PreparedProbe& p, glm::vec3 x, glm::vec3 n) {
    const dvec3 xd(x), nd(glm::normalize(n));
    dvec3 sum(0.0);
    for (const PreparedProbe::Texel& t : p.texels) {
        if (t.radiance == glm::vec3(0.0f)) continue;
        const dvec3 to_light = dvec3(t.centre) - xd;
        const double r2 = glm::dot(to_light, to_light);
        if (!(r2 > 0.0)) continue;  // x exactly on the virtual light: undefined, skipped
        const double r = std::sqrt(r2);
        const double cos_x = glm::dot(nd, to_light) / r;
        const double cos_y = -glm::dot(dvec3(t.normal), to_light) / r;
        if (cos_x <= 0.0 || cos_y <= 0.0) continue;
        sum += dvec3(t.radiance) * (cos_x * cos_y * double(t.area) / (kPi * r2));
    }
    return glm::vec3(sum);
}

namespace {

// The texel of an M x M cube grid that direction d (not 0) passes through.
size_t texel_towards(int m, dvec3 d) {
    const dvec3 a = glm::abs(d);
    const int axis = a.x >= a.y && a.x >= a.z ? 0 : a.y >= a.z ? 1 : 2;
    const int face = 2 * axis + (d[axis] < 0.0 ? 1 : 0);
    const glm::dvec2 uv = cube_face_uv(face, d / a[axis]);
    const int i = std::clamp(int(uv.x * m), 0, m - 1), j = std::clamp(int(uv.y * m), 0, m - 1);
    return (size_t(face) * m + size_t(j)) * m + size_t(i);
}

}  // namespace

namespace {

// The distance from the probe along the unit direction u (in texel t's
// cone) to t's polygon: to the plane of whichever of its two triangles
// (split along corners 0-2) holds u; 0 where u runs along that plane.
double polygon_depth(const PreparedProbe::Texel& t, dvec3 probe, dvec3 u) {
    dvec3 c[4];
    for (int k = 0; k < 4; ++k) c[k] = dvec3(t.corners[k]) - probe;
    const dvec3 split = glm::cross(c[0], c[2]);
    const dvec3 b = glm::dot(split, u) * glm::dot(split, c[1]) >= 0.0 ? c[1] : c[3];
    const dvec3 normal = glm::cross(b - c[0], c[2] - c[0]);
    const double along = glm::dot(normal, u);
    return along == 0.0 ? 0.0 : glm::dot(normal, c[0]) / along;
}

// The longer diagonal of t's polygon: how far a chord across a room's edge
// can lie from the walls it cuts across.
double polygon_reach(const PreparedProbe::Texel& t) {
    return std::max(glm::length(t.corners[2] - t.corners[0]), glm::length(t.corners[3] - t.corners[1]));
}

}  // namespace

// The paper's polygons (its eq. 1 over each texel's quadrilateral) enclose
// the probe like a room's walls: at a point inside them, their projections
// tile the sphere of directions, and a uniformly bright room gives exactly
// its radiance. A texel whose corners land on two or three walls (it sees a
// room's edge or corner) is a chord across that edge, short of the walls; a
// point between the chord and the walls (1 cm above the floor, 10 cm from two
// walls) is outside the polygons, sees the chord's back, and their form
// factors cancel: -26% in the furnace test, up to -76% 1 cm from three walls.
// Such a point is evaluated where the line from the probe to it meets the
// chord, just inside. Only where all four corners are on surfaces (traced:
// the gap between a chord and its walls is then at most its diagonal), and
// only by as much: a point farther beyond is behind a surface the probe sees,
// and is left where it is.
glm::vec3 probe_point_inside(const PreparedProbe& p, glm::vec3 x) {
    const dvec3 probe(p.position), r = dvec3(x) - probe;
    const double distance = glm::length(r);
    if (!(distance > 0.0)) return x;
    const PreparedProbe::Texel& t = p.texels[texel_towards(p.m, r)];
    if (!t.corners_traced) return x;  // a corner placed by a rule, not on a surface: the polygon may be anywhere
    const double wall = polygon_depth(t, probe, r / distance);
    if (!(wall > 0.0) || distance <= wall || distance - wall > polygon_reach(t)) return x;
    return glm::vec3(probe + r * (wall / distance * (1.0 - 1e-4)));
}

namespace {

// How far beyond the surface a point may lie and still count as on it: the
// corner rays' float rounding and a shading point's own (2·10⁻⁴ of the
// distance, 50 µm at least), well under the thinnest wall a scene has
// (1 mm at 4 m).
double on_surface_tolerance(double distance) { return 2e-4 * distance + 5e-5; }

// A plane (a point on it and its unit normal towards the probe), as the
// flat texel `texel` sees it.
struct FacingPlane {
    dvec3 point, normal;
    size_t texel;
    double ahead(dvec3 y) const { return glm::dot(normal, y - point); }  // > 0 on the probe's side
};

// The planes of the flat texels around t, across its four edges and its
// four corners (relative to the probe): the surfaces whose edge t sees,
// where those texels see them.
std::vector<FacingPlane> neighbour_planes(const PreparedProbe& p, const PreparedProbe::Texel& t) {
    std::vector<FacingPlane> planes;
    for (int k = 0; k < 8; ++k) {
        const dvec3 a(t.corner_directions[k % 4]), b(t.corner_directions[(k + k / 4) % 4]);
        const dvec3 mid = glm::normalize(a + b);                      // an edge's midpoint (k < 4), or a corner
        const dvec3 across = mid + 0.5 * (mid - dvec3(t.direction));  // into the texel beyond it
        const size_t beside = texel_towards(p.m, across);
        const PreparedProbe::Texel& n = p.texels[beside];
        if (&n == &t || !n.planar) continue;
        planes.push_back({dvec3(n.corners[0]) - dvec3(p.position), dvec3(n.normal), beside});
    }
    return planes;
}

// Whether t sees a room's inner edge or corner: every corner of t on or in
// front of each of the planes beside it (the walls enclose the probe).
bool inner_edge(const PreparedProbe& p, const PreparedProbe::Texel& t, const std::vector<FacingPlane>& planes) {
    for (const FacingPlane& plane : planes)
        for (int k = 0; k < 4; ++k)
            if (plane.ahead(dvec3(t.corners[k]) - dvec3(p.position)) < -on_surface_tolerance(glm::length(plane.point)))
                return false;
    return !planes.empty();
}

// The distance from the probe along unit d to the plane, 0 where d does not meet it ahead.
double depth_along(const FacingPlane& plane, dvec3 d) {
    const double along = glm::dot(plane.normal, d);
    const double depth = along == 0.0 ? 0.0 : glm::dot(plane.normal, plane.point) / along;
    return depth > 0.0 && depth < kMissDistance ? depth : 0.0;
}

// A texel whose corners lie on two surfaces, neither enclosing the other (a
// depth jump: a partition's top edge against the ceiling behind it, an
// emitter's edge against the floor; or an outer edge), has a polygon that
// bridges the two: seen from beside, it is a wall from the nearer surface's
// edge to the farther surface, where the probe saw neither. In a uniformly
// bright room that is right (the polygons stay closed, and exact: the
// furnace tests), but with the texel's mean radiance an emitter's edge
// texel hangs a lit curtain from the emitter to the floor (+160% 5 cm under
// a tilted emitter's low edge, issue #52). So the bridge carries the farther
// surface's radiance (its flat neighbour's: what the probe could not see
// behind the edge is most like it), and the rest of the texel's radiance,
// its own less that, lies on the nearer surface's plane across the texel's
// cone: the probe still sees the texel's mean (the two polygons subtend the
// same solid angle from it), a uniform room still gets a zero rest, and the
// emitter's light stays in the emitter's plane.
void split_bridges(PreparedProbe& p) {
    for (PreparedProbe::Texel& t : p.texels) {
        if (!t.corners_traced || t.planar) continue;
        const std::vector<FacingPlane> planes = neighbour_planes(p, t);
        if (planes.empty() || inner_edge(p, t, planes)) continue;
        const FacingPlane *nearest = nullptr, *farthest = nullptr;
        double near_depth = 0.0, far_depth = 0.0;
        for (const FacingPlane& plane : planes) {
            const double depth = depth_along(plane, dvec3(t.direction));
            if (depth <= 0.0) continue;
            if (!nearest || depth < near_depth) nearest = &plane, near_depth = depth;
            if (!farthest || depth > far_depth) farthest = &plane, far_depth = depth;
        }
        if (!nearest || nearest == farthest) continue;
        // The nearer plane across the texel must stay in front of the
        // texel's farthest corner (a plane seen at a grazing angle, continued
        // across a coarse texel, can run off far beyond it).
        double farthest_corner = 0.0;
        for (const glm::vec3& c : t.corners)
            farthest_corner = std::max(farthest_corner, double(glm::length(c - p.position)));
        std::array<glm::vec3, 4> near_corners{};
        bool all = true;
        for (int k = 0; k < 4 && all; ++k) {
            const dvec3 d(t.corner_directions[k]);
            const double depth = depth_along(*nearest, d);
            all = depth > 0.0 && depth <= farthest_corner;
            near_corners[size_t(k)] = p.position + glm::vec3(d * depth);
        }
        if (!all) continue;
        // Only where the nearer surface adds light (an emitter's or a lit
        // edge against a darker background): a darker one's rest would be
        // negative light across the whole texel's cone, subtracted in
        // directions the occluder does not cover (the Cornell box at M 4:
        // 57% off halfway to the red wall, 0.13 -> 0.18 over random points).
        const glm::vec3 rest = t.radiance - p.texels[farthest->texel].radiance;
        if (std::min({rest.r, rest.g, rest.b}) < 0.0f) continue;
        t.split = true;
        t.near_corners = near_corners;
        t.bridge_radiance = p.texels[farthest->texel].radiance;
    }
}

}  // namespace

// Visibility from the probe's own distances, texel by texel (the texel
// towards x):
// - a flat texel (its four corners traced and coplanar) sees one plane,
//   and that plane is its polygon: x is seen when it is no farther along
//   the line than the polygon, up to on_surface_tolerance. Exact: a point
//   1 mm behind a 1 mm wall is not seen.
// - a texel across a room's inner edge or corner (its corners on two or
//   three walls) is a chord short of the walls; the walls' planes are those
//   of the flat texels beside it. When every corner lies on or in front of
//   each such plane (an inner edge: the walls enclose the probe), x is seen
//   when it is in front of every one of them (the room's own side of both
//   walls, however far beyond the chord).
// - otherwise (an outer edge, a depth jump, a corner whose ray escaped),
//   only the polygon is known: x is seen up to the polygon's diagonal beyond
//   it (probe_point_inside's reach), or beyond the farthest corner that met
//   a surface; a texel that met nothing hides nothing.
bool probe_sees(const PreparedProbe& p, glm::vec3 x) {
    const dvec3 probe(p.position), r = dvec3(x) - probe;
    const double distance = glm::length(r);
    if (!(distance > 0.0)) return true;
    const PreparedProbe::Texel& t = p.texels[texel_towards(p.m, r)];
    const double tolerance = on_surface_tolerance(distance);
    if (!t.corners_traced) {
        if (t.distance >= kMissDistance) return true;
        double farthest = t.distance;
        for (int k = 0; k < 4; ++k) {
            const double d = glm::length(dvec3(t.corners[k]) - probe);
            if (d < 0.5 * kMissDistance) farthest = std::max(farthest, d);
        }
        return distance <= farthest + polygon_reach(t);
    }
    const double wall = polygon_depth(t, probe, r / distance);
    if (t.planar) return !(wall > 0.0) || distance <= wall + tolerance;
    const std::vector<FacingPlane> planes = neighbour_planes(p, t);
    if (inner_edge(p, t, planes)) {
        for (const FacingPlane& plane : planes)
            if (plane.ahead(r) < -tolerance) return false;
        return true;
    }
    return !(wall > 0.0) || distance <= wall + polygon_reach(t);
}

// The texel polygons, each split into two triangles along corners 0-2 (those
// probe_point_inside reads), form one closed surface around the probe: the
// triangles of neighbouring texels share their corners. Seen from a point x
// inside it, every direction of x's hemisphere crosses that surface an odd
// number of times, alternately through a triangle's front (+) and its back
// (-): where an occluder's edge lies across a texel, the texel beside it
// joins the occluder to the wall behind, and from a point beside the
// occluder that texel faces away. So the signed sum of the triangles' form
// factors, each clipped to x's horizon (exact for a planar triangle), is the
// exact projected solid angle for uniform radiance in any room, not only a
// convex one. Two ways to lose that: the paper's clamp (max(F, 0) per texel
// of the unclipped sum) drops the above-horizon part of a texel that
// straddles the tangent plane (-53% 1 cm from two walls of a furnace), and a
// clamp per clipped texel drops the back-facing ones and counts the wall
// behind an occluder twice (+35% 1 cm from a block's foot in the Cornell
// box; tests/test_probes.cpp). The total is clamped at 0 (a point outside the
// surface, where the signed terms cancel, up to noise).
namespace {

// The form factor from x (unit normal n) to a texel's polygon, as its two
// triangles (split along corners 0-2) each clipped to x's horizon, signed.
double clipped_texel_form_factor(const std::array<glm::vec3, 4>& corners, dvec3 x, dvec3 n) {
    dvec3 r[4];
    for (int c = 0; c < 4; ++c) r[c] = dvec3(corners[c]) - x;
    int above = 0;
    for (const dvec3& c : r) above += glm::dot(n, c) >= 0.0;
    if (above == 0) return 0.0;
    // Wholly above, the two triangles' shared edge cancels: the quad's own sum.
    const dvec3 second[3] = {r[0], r[2], r[3]};
    return above == 4 ? lambert_sum(r, 4, n) : clipped_sum(r, 3, n) + clipped_sum(second, 3, n);
}

}  // namespace

glm::vec3 probe_polygon_to_point(const PreparedProbe& p, glm::vec3 x, glm::vec3 n, bool clip_to_horizon) {
    const dvec3 xd(probe_point_inside(p, x)), nd(glm::normalize(n));
    dvec3 sum(0.0);
    for (const PreparedProbe::Texel& t : p.texels) {
        if (!clip_to_horizon) {  // the paper's: max(F, 0) of the whole quad
            dvec3 r[4];
            for (int c = 0; c < 4; ++c) r[c] = dvec3(t.corners[c]) - xd;
            sum += dvec3(t.radiance) * std::max(lambert_sum(r, 4, nd), 0.0);
            continue;
        }
        // A split texel: the bridge at the farther surface's radiance, the
        // rest on the nearer surface's plane (split_bridges).
        const glm::vec3 radiance = t.split ? t.bridge_radiance : t.radiance;
        if (radiance != glm::vec3(0.0f)) sum += dvec3(radiance) * clipped_texel_form_factor(t.corners, xd, nd);
        if (t.split && t.radiance != t.bridge_radiance)
            sum += dvec3(t.radiance - t.bridge_radiance) * clipped_texel_form_factor(t.near_corners, xd, nd);
    }
    return glm::vec3(glm::max(sum, dvec3(0.0)));
}

glm::vec3 probe_convolved_irradiance(const PreparedProbe& p, glm::vec3 n) {
    const dvec3 nd(glm::normalize(n));
    dvec3 sum(0.0);
    for (const PreparedProbe::Texel& t : p.texels) {
        if (t.radiance == glm::vec3(0.0f)) continue;
        dvec3 r[4];
        for (int c = 0; c < 4; ++c) r[c] = dvec3(t.corner_directions[c]);
        sum += dvec3(t.radiance) * std::max(clipped_sum(r, 4, nd), 0.0);
    }
    return glm::vec3(sum);
}

glm::vec2 probe_distance_moments(const PreparedProbe& p, glm::vec3 w, float power) {
    const dvec3 wd(glm::normalize(w));
    double sw = 0.0, s1 = 0.0, s2 = 0.0;
    for (const PreparedProbe::Texel& t : p.texels) {
        const double c = glm::dot(wd, dvec3(t.direction));
        if (c <= 0.0) continue;
        const double weight = std::pow(c, double(power)) * t.solid_angle;
        sw += weight;
        s1 += weight * t.distance;
        s2 += weight * double(t.distance) * t.distance;
    }
    if (!(sw > 0.0)) return {kMissDistance, double(kMissDistance) * kMissDistance};
    return {float(s1 / sw), float(s2 / sw)};
}

float ddgi_probe_weight(const PreparedProbe& p, glm::vec3 x, glm::vec3 n, const ProbeEvalOptions& options) {
    const glm::vec3 nn = glm::normalize(n);
    // Backface: probes behind the surface count less (smooth, never zero).
    const glm::vec3 to_probe = p.position - x;
    const float to_probe_len = glm::length(to_probe);
    const float cos_back = to_probe_len > 0.0f ? glm::dot(to_probe / to_probe_len, nn) : 1.0f;
    const float wrap = std::max(1e-4f, (cos_back + 1.0f) * 0.5f);
    double weight = double(wrap) * wrap + 0.2;
    // Visibility: Chebyshev's bound on the chance that the surface towards x
    // is at least as far as x, from the distance moments in that direction.
    const glm::vec3 v = x + options.ddgi_normal_bias * nn - p.position;
    const double dist = glm::length(v);
    double chebyshev = 1.0;
    if (dist > 1e-6) {
        const glm::vec2 moments = probe_distance_moments(p, v / float(dist), options.ddgi_moment_power);
        const double mean = moments.x;
        if (dist > mean) {
            const double variance = std::abs(mean * mean - double(moments.y));
            chebyshev = variance / (variance + (dist - mean) * (dist - mean));
            chebyshev = std::max(chebyshev * chebyshev * chebyshev, 0.0);
        }
    }
    weight *= std::max(0.05, chebyshev);
    weight = std::max(weight, 1e-6);
    const double crush = 0.2;
    if (weight < crush) weight *= weight * weight / (crush * crush);
    return float(weight);
}

ProbeEvaluation evaluate_probe(const PreparedProbe& p, glm::vec3 x, glm::vec3 n, const ProbeEvalOptions& options) {
    ProbeEvaluation e;
    e.sh9 = probe_sh9(p, n);
    e.point_to_point = probe_point_to_point(p, x, n);
    e.polygon_to_point = probe_polygon_to_point(p, x, n, options.clip_to_horizon);
    e.ddgi = probe_convolved_irradiance(p, n);
    return e;
}

// ------------------------------------------------------------- sets ----

ProbeEvaluator::ProbeEvaluator(const ProbeSet& set, ProbeEvalOptions options) : options_(options) {
    const size_t n = set.probes.size();
    prepared_.resize(n);
    valid_.assign(n, false);
    for (size_t k = 0; k < n; ++k) {
        if (!set.probes[k].valid) continue;
        prepared_[k] = prepare_probe(set.probes[k], set.m);
        valid_[k] = true;
        ++valid_count_;
    }
    if (valid_count_ == 0) throw std::invalid_argument("the probe set has no valid probe");

    // A full regular lattice? (All probes, valid or not, on distinct lattice
    // points: where the placement put them, a moved probe's moved_from.)
    const auto home = [](const Probe& p) { return p.moved_from.value_or(p.position); };
    glm::vec3 lo(1e30f), hi(-1e30f);
    for (const Probe& p : set.probes) {
        lo = glm::min(lo, home(p));
        hi = glm::max(hi, home(p));
    }
    const float tolerance = 1e-4f * (1.0f + glm::length(hi - lo));
    size_t cells = 1;
    for (int a = 0; a < 3; ++a) {
        std::vector<float> values;
        for (const Probe& p : set.probes) values.push_back(home(p)[a]);
        std::sort(values.begin(), values.end());
        for (float v : values)
            if (axis_[a].empty() || v - axis_[a].back() > tolerance) axis_[a].push_back(v);
        cells *= axis_[a].size();
    }
    if (cells != n) return;
    // A lattice is evenly spaced on each axis.
    for (int a = 0; a < 3; ++a)
        for (size_t i = 2; i < axis_[a].size(); ++i) {
            const float step = axis_[a][1] - axis_[a][0];
            if (std::abs(axis_[a][i] - axis_[a][0] - step * float(i)) > tolerance) return;
        }
    lattice_.assign(n, -1);
    for (size_t k = 0; k < n; ++k) {
        size_t index = 0;
        for (int a = 2; a >= 0; --a) {
            const auto& axis = axis_[a];
            const auto it = std::lower_bound(axis.begin(), axis.end(), home(set.probes[k])[a] - tolerance);
            index = index * axis.size() + size_t(it - axis.begin());
        }
        if (index >= n || lattice_[index] != -1) {
            lattice_.clear();
            return;
        }
        lattice_[index] = int(k);
    }
    grid_ = true;
}

template <class Usable>
std::vector<std::pair<int, float>> ProbeEvaluator::blend(glm::vec3 x, const Usable& usable) const {
    std::vector<std::pair<int, float>> out;
    if (grid_) {
        int i0[3];
        float f[3];
        for (int a = 0; a < 3; ++a) {
            const auto& axis = axis_[a];
            if (axis.size() == 1) {
                i0[a] = 0;
                f[a] = 0.0f;
                continue;
            }
            const int i = int(std::upper_bound(axis.begin(), axis.end(), x[a]) - axis.begin()) - 1;
            i0[a] = std::clamp(i, 0, int(axis.size()) - 2);
            f[a] = std::clamp((x[a] - axis[i0[a]]) / (axis[i0[a] + 1] - axis[i0[a]]), 0.0f, 1.0f);
        }
        double total = 0.0;
        for (int corner = 0; corner < 8; ++corner) {
            float w = 1.0f;
            size_t index = 0;
            bool outside = false;
            for (int a = 2; a >= 0; --a) {
                const int bit = (corner >> a) & 1;
                if (bit && axis_[a].size() == 1) outside = true;
                w *= bit ? f[a] : 1.0f - f[a];
                index = index * axis_[a].size() + size_t(i0[a] + bit);
            }
            if (outside || w <= 0.0f) continue;
            const int k = lattice_[index];
            if (!valid_[size_t(k)] || !usable(k)) continue;
            out.push_back({k, w});
            total += w;
        }
        if (total > 0.0) {
            for (auto& [k, w] : out) w = float(w / total);
            return out;
        }
        out.clear();  // no corner of the cell is usable: fall back to the nearest usable probes
    }
    std::vector<std::pair<float, int>> by_distance;
    for (size_t k = 0; k < prepared_.size(); ++k)
        if (valid_[k] && usable(int(k))) by_distance.push_back({glm::length(prepared_[k].position - x), int(k)});
    if (by_distance.empty()) return {};
    std::sort(by_distance.begin(), by_distance.end());
    if (by_distance.front().first < 1e-6f || by_distance.size() == 1) return {{by_distance.front().second, 1.0f}};
    const size_t count = std::min<size_t>(8, by_distance.size());
    const double radius = count < by_distance.size() ? by_distance[count].first : by_distance[count - 1].first * 1.5;
    double total = 0.0;
    for (size_t i = 0; i < count; ++i) {
        const double d = by_distance[i].first;
        const double w = std::pow(std::max(0.0, radius - d) / (radius * d), 2.0);
        if (w <= 0.0) continue;
        out.push_back({by_distance[i].second, float(w)});
        total += w;
    }
    if (total <= 0.0) {  // every one of them as far as the next: equal weights
        out.clear();
        for (size_t i = 0; i < count; ++i) out.push_back({by_distance[i].second, 1.0f / float(count)});
        return out;
    }
    for (auto& [k, w] : out) w = float(w / total);
    return out;
}

std::vector<std::pair<int, float>> ProbeEvaluator::weights(glm::vec3 x) const {
    return blend(x, [](int) { return true; });
}

std::vector<std::pair<int, float>> ProbeEvaluator::visible_weights(glm::vec3 x) const {
    return blend(x, [&](int k) { return probe_sees(prepared_[size_t(k)], x); });
}

ProbeEvaluation ProbeEvaluator::evaluate(glm::vec3 x, glm::vec3 n) const {
    ProbeEvaluation e;
    for (const auto& [k, w] : visible_weights(x)) {
        const PreparedProbe& p = prepared_[size_t(k)];
        e.sh9 += w * probe_sh9(p, n);
        e.point_to_point += w * probe_point_to_point(p, x, n);
        e.polygon_to_point += w * probe_polygon_to_point(p, x, n, options_.clip_to_horizon);
    }
    double ddgi_total = 0.0;
    for (const auto& [k, w] : weights(x)) {
        const PreparedProbe& p = prepared_[size_t(k)];
        const float dw = w * ddgi_probe_weight(p, x, n, options_);
        e.ddgi += dw * probe_convolved_irradiance(p, n);
        ddgi_total += dw;
    }
    if (ddgi_total > 0.0) e.ddgi /= float(ddgi_total);
    return e;
}

ProbeEvaluation evaluate(const ProbeSet& set, glm::vec3 x, glm::vec3 n, const ProbeEvalOptions& options) {
    return ProbeEvaluator(set, options).evaluate(x, n);
}

size_t probe_buffer_stride(int m) {
    const size_t texels = size_t(6) * m * m;
    return texels + (size_t(6) * (m + 1) * (m + 1) + 3) / 4 + (texels + 3) / 4 + 2 * texels + 9;
}

std::vector<glm::vec4> pack_probe_buffer(const ProbeSet& set) {
    const int m = set.m;
    const size_t stride = probe_buffer_stride(m), texels = size_t(6) * m * m;
    std::vector<glm::vec4> out(stride * set.probes.size(), glm::vec4(0.0f));
    for (size_t k = 0; k < set.probes.size(); ++k) {
        const Probe& p = set.probes[k];
        if (!p.valid || p.radiance.size() != texels || p.distance.size() != texels) continue;
        glm::vec4* block = out.data() + k * stride;
        for (size_t t = 0; t < texels; ++t) block[t] = glm::vec4(p.radiance[t], p.distance[t]);
        const std::vector<float> corners = probe_corner_distances(p, m);
        for (size_t c = 0; c < corners.size(); ++c) {
            const bool traced = c < p.corner_distance.size() && p.corner_distance[c] < kMissDistance;
            block[texels + c / 4][int(c % 4)] = traced ? corners[c] : -corners[c];
        }
        if (p.centre_distance.size() == texels) {
            glm::vec4* centres = block + texels + (corners.size() + 3) / 4;
            for (size_t t = 0; t < texels; ++t) centres[t / 4][int(t % 4)] = p.centre_distance[t];
        }
        // The split texels (split_bridges): the bridge's radiance and 1, then
        // the nearer plane's corners as distances along the corner directions.
        const PreparedProbe prepared = prepare_probe(p, m);
        glm::vec4* splits = block + texels + (corners.size() + 3) / 4 + (texels + 3) / 4;
        for (size_t t = 0; t < texels; ++t) {
            const PreparedProbe::Texel& texel = prepared.texels[t];
            if (!texel.split) continue;
            splits[2 * t] = glm::vec4(texel.bridge_radiance, 1.0f);
            for (int c = 0; c < 4; ++c)
                splits[2 * t + 1][c] = glm::length(texel.near_corners[size_t(c)] - prepared.position);
        }
        // The SH9, the reference point in the first three's w (a moved
        // probe's differs from its lattice point: lf_probe_reference_point).
        glm::vec4* sh9 = block + stride - 9;
        for (int k = 0; k < 9; ++k) sh9[k] = glm::vec4(p.sh9[size_t(k)], k < 3 ? p.position[k] : 0.0f);
    }
    return out;
}

std::vector<ShadingPoint> read_shading_points(const std::filesystem::path& points_json) {
    const std::string file = points_json.string();
    std::ifstream in(points_json);
    if (!in) throw std::runtime_error(file + ": cannot be read");
    const nlohmann::json doc = nlohmann::json::parse(in, nullptr, false);
    const std::string shape = R"( must be [{"position": [x,y,z], "normal": [x,y,z]}, ...])";
    if (!doc.is_array()) throw std::runtime_error(file + shape);
    const auto vec3 = [&](const nlohmann::json& p, const char* key, size_t i) {
        const nlohmann::json* v = p.is_object() && p.contains(key) ? &p[key] : nullptr;
        if (!v || !v->is_array() || v->size() != 3 || !(*v)[0].is_number() || !(*v)[1].is_number() ||
            !(*v)[2].is_number())
            throw std::runtime_error(file + ": point " + std::to_string(i) + ": " + key + shape);
        const glm::vec3 r((*v)[0].get<float>(), (*v)[1].get<float>(), (*v)[2].get<float>());
        if (!std::isfinite(r.x) || !std::isfinite(r.y) || !std::isfinite(r.z))
            throw std::runtime_error(file + ": point " + std::to_string(i) + ": " + key + " is not finite");
        return r;
    };
    std::vector<ShadingPoint> points;
    for (size_t i = 0; i < doc.size(); ++i) {
        const glm::vec3 position = vec3(doc[i], "position", i), normal = vec3(doc[i], "normal", i);
        if (glm::length(normal) == 0.0f)
            throw std::runtime_error(file + ": point " + std::to_string(i) + ": normal is zero");
        points.push_back({position, glm::normalize(normal)});
    }
    return points;
}

nlohmann::json evaluate_at_points(const ProbeSet& set, const std::vector<ShadingPoint>& points) {
    const ProbeEvaluator evaluator(set);  // throws when no probe is valid
    const auto rgb = [](glm::vec3 c) { return nlohmann::json{c.r, c.g, c.b}; };
    nlohmann::json out = {{"points", nlohmann::json::array()}};
    for (const ShadingPoint& p : points) {
        const ProbeEvaluation e = evaluator.evaluate(p.position, p.normal);
        out["points"].push_back({{"sh9", rgb(e.sh9)},
                                 {"point_to_point", rgb(e.point_to_point)},
                                 {"polygon_to_point", rgb(e.polygon_to_point)},
                                 {"ddgi", rgb(e.ddgi)}});
    }
    return out;
}

}  // namespace lf
