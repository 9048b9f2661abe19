// UV seams: edges that are one edge in 3D but two in the lightmap atlas.
//
// Both sides of a seam store the same surface points in different texels; if
// they disagree, the seam shows as a line. find_seams locates them (within a
// mesh and between meshes that touch), seam_metric measures the disagreement,
// and stitch_seams makes the texels along both sides agree.
#pragma once

#include "scene/scene.h"

#include <glm/glm.hpp>

#include <array>
#include <cstdint>
#include <vector>

namespace lf {

struct SeamEdge {
    // UV1 endpoints on side A and on side B; a0 and b0 are the same 3D point,
    // as are a1 and b1.
    glm::vec2 a0, a1, b0, b1;
    // The shading normals agree across the seam at both ends (within ~10°):
    // the surface is smooth there and both sides should show the same light.
    // A crease (the edge of a cube) is a seam too, but its two sides face
    // different ways and legitimately differ.
    bool smooth = false;
};

// Pairs of triangle edges whose endpoints coincide in 3D (within 1e-5 of the
// scene's diagonal, either orientation, any meshes) but whose UV1 endpoints
// differ (by more than 1e-6 in UV). An edge shared by more than two triangles
// yields one seam per pair of sides that differ. Edges that meet a T-junction
// (one long edge against two short ones) are not matched, nor edges of a
// mesh without a lightmap (PrimitiveInstance::has_lightmap: its one texel
// per chart is no side to stitch a lightmapped neighbour to).
std::vector<SeamEdge> find_seams(const Scene& scene);

// Bilinear lookup in a width x height image (row-major from the top) at glTF
// UV `uv`: pixel (u·W, v·H), texel centres at half-integers, clamped at the
// image border.
glm::vec4 sample_bilinear(const std::vector<glm::vec4>& image, int width, int height, glm::vec2 uv);

// Mean over seams and over `samples_per_edge` points per seam, at parameters
// t = (k + ½) / samples_per_edge along the edge, of
//     |A(t) - B(t)|, averaged over the R, G and B channels,
// where A(t) = bilinear(image, mix(a0, a1, t)) and B(t) likewise on side B.
// Every seam edge counts equally whatever its length. 0 if there are no seams.
double seam_metric(const std::vector<SeamEdge>& seams, const std::vector<glm::vec4>& image, int width, int height,
                   int samples_per_edge = 8);

// Least-squares stitching (as in The Witness, Bakery and Godot): changes the
// texels that the seams' bilinear lookups read so that both sides agree,
// minimising
//     Σ_seam points |A(t) - B(t)|²  +  λ Σ_texels |texel - original|²
// by conjugate gradients (`iterations` steps; all four channels solved
// together, independently), subject to texel >= 0 when `non_negative`
// (irradiance is never negative: components that go negative are held at 0
// and the rest solved again); signed data (a directional lightmap's L1
// vectors) is stitched without it. Only texels the lookups touch change. Run
// it after dilation (dilation would overwrite stitched padding texels).
//
// The system (which texels, which rows) depends on the seams and the atlas
// size only: a bake builds it once and stitches every layer of every
// snapshot with it, from any thread (stitch() changes nothing of it).
class SeamStitcher {
public:
    SeamStitcher(const std::vector<SeamEdge>& seams, int width, int height, int samples_per_edge = 8);
    void stitch(std::vector<glm::vec4>& image, float lambda = 0.1f, int iterations = 64,
                bool non_negative = true) const;

    struct RowTap {
        uint32_t unknown;
        float weight;
    };
    using Row = std::array<RowTap, 8>;  // +bilinear weights on side A, -bilinear weights on side B

private:
    int width_, height_;
    std::vector<uint32_t> pixel_of_unknown_;
    std::vector<Row> rows_;  // one per seam point
};

// SeamStitcher(seams, width, height, samples_per_edge).stitch(image, …), for one image.
void stitch_seams(const std::vector<SeamEdge>& seams, std::vector<glm::vec4>& image, int width, int height,
                  int samples_per_edge = 8, float lambda = 0.1f, int iterations = 64, bool non_negative = true);

}  // namespace lf
