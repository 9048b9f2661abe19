// Radiosity maps (Moreno-Fortuny 2005): a lightmap atlas whose texels gather
// direct light by shadow rays to the emitters and indirect light by
// cosine-distributed rays that read the current radiosity map, pass by pass.
#pragma once

#include "atlas/texel_samples.h"
#include "bake/method_state.h"
#include "bake/progressive.h"
#include "bake/scene_shading.h"
#include "trace/surface_textures.h"
#include "gpu/shader.h"
#include "io/image_files.h"
#include "scene/scene.h"
#include "shaders/radiosity_params.glsl"
#include "trace/tracer.h"

#include <glm/glm.hpp>

#include <optional>
#include <string>
#include <vector>

namespace lf {

// How the indirect estimate is refined from pass to pass.
enum class RadiosityScheme {
    // The thesis's single-sample transport (eq. 3.14-3.15): one running
    // average of every indirect sample, each read from the solution as it
    // was. Early samples saw a dark scene, so bounce k is weighted by
    // kappa_k < 1 (eq. 3.17-3.18): biased at any finite pass count.
    Thesis,
    // Doubling epochs (passes 1 | 2 | 3-4 | 5-8 | …): the indirect average
    // restarts at each epoch, from a solution that already holds the previous
    // epochs' bounces, so old dark samples are dropped and the bias falls
    // geometrically with the epoch count instead of like 1/passes.
    DoublingEpochs,
    // Doubling epochs with a final gather: where an indirect ray lands, its
    // first bounce is computed there (the hit point's direct light by the
    // same light sampling as the texels', times its albedo) and only the
    // light beyond is read from the map (albedo x the map's indirect layer).
    // The map then supplies light that has bounced at least once, which is
    // smooth, so the bias of its resolution (shadow edges, lamp pools,
    // corners smeared into the gather) falls with it; one more shadow ray per
    // texel per pass.
    FinalGather,
    // The baseline: brute-force path tracing per texel (next-event estimation
    // at every vertex), no radiosity map read. Unbiased, and slow to converge.
    PathTracing,
};

// How the emitters' direct light is sampled.
enum class LightSampling {
    // Multiple importance sampling of solid-angle sampling and the indirect cosine ray (the default).
    Mis,
    // Points uniform in area on a power-chosen triangle alone (thesis eq. 3.12).
    Area,
    // Directions uniform in the triangle's solid angle alone (Arvo 1995; thesis §6.3).
    SolidAngle,
};

const char* to_string(LightSampling sampling);
LightSampling parse_light_sampling(const std::string& text);  // "mis" | "area" | "solid-angle"

const char* to_string(RadiosityScheme scheme);
RadiosityScheme parse_radiosity_scheme(const std::string& text);  // "epochs" | "final-gather" | "thesis" | "pathtrace"

struct RadiosityMapSettings {
    RadiosityScheme scheme = RadiosityScheme::DoublingEpochs;
    int light_samples = 1;  // emitter samples per texel per pass
    LightSampling light_sampling = LightSampling::Mis;
    uint32_t seed = 1;
    const Environment* environment = nullptr;  // what escaping rays see (null: black); the caller keeps it
    // > 0: a texel whose own relative standard error falls below this stops
    // tracing (adaptive sampling); set from the bake's target error.
    double converged_texel_error = 0.0;
    // Directional lightmaps: each texel's L1 vector too (image layers L1x,
    // L1y, L1z; direct_light.glsl's lf_add_directional).
    bool directional = false;
    // Passes one dispatch may run, 1 to kMaxPassesPerDispatch; 0:
    // passes_per_dispatch_for(the covered texels).
    int passes_per_dispatch = 0;
};

// A pass of a small atlas is too little work for a GPU: an H100 keeps
// 132 x 2048 = 270,336 threads resident, and a 256² Cornell box has 40,555
// texels. So one dispatch runs several passes, as many as bring its texel
// passes to kTexelPassesPerDispatch (a power of two, at most
// kMaxPassesPerDispatch). Those passes read the map published at the start
// of their cell (cell_end_after), up to that many passes old; it is
// published again at the cell's end. A software renderer runs one: any pass fills
// its cores, and the loop over passes costs llvmpipe a quarter of its speed
// (docs/BENCHMARKS.md, "Several passes per dispatch").
inline constexpr size_t kTexelPassesPerDispatch = size_t(1) << 18;
inline constexpr int kMaxPassesPerDispatch = 16;
int passes_per_dispatch_for(size_t covered_texels, bool software_renderer);

// The cells: runs of passes that read one publication of the map. The
// passes from 2^j to 2^(j+1) (an epoch of RadiosityScheme::DoublingEpochs)
// are cut into cells of 2^j / kPublicationsPerDoubling passes, at least 1
// and at most passes_per_dispatch, so that the map is published at least
// that many times each time the pass count doubles: a pass reads a map at
// most 1/16 of the bake old, and light keeps bouncing (the furnace with a
// fixed 16 passes per cell fell 2.5% short of Le / (1 - rho) at 256 passes).
// Returns the pass count at which the cell of pass number `pass` (0-based) ends.
inline constexpr int kPublicationsPerDoubling = 16;
int cell_end_after(int pass, int passes_per_dispatch);

class RadiosityMapBaker {
public:
    // The scene must carry lightmap UVs (uv1) matching `texels`. The tracer
    // is shared: one BVH for every method of a bake.
    RadiosityMapBaker(const Scene& scene, const TexelSamples& texels, const Tracer& tracer,
                      const RadiosityMapSettings& settings);

    // Runs `count` passes (1 <= count <= max_batch()) back to back and
    // returns the totals after each. Nothing is read back between them: the
    // device is waited for once, after the last, and each pass's totals
    // (rays, error) come from its own slot of the partial sums.
    //
    // The passes fall into cells (cell_end_after). Every pass of a cell
    // reads the map published at the cell's start, and the map is published
    // again at its end; a cell is one dispatch, or two where a batch ends
    // inside it. So the pixels depend on the pass count and
    // passes_per_dispatch(), not on how passes are batched.
    std::vector<PassStats> run_passes(int count);
    PassStats step() { return run_passes(1).back(); }
    int max_batch() const { return max_batch_; }
    int passes_per_dispatch() const { return passes_per_dispatch_; }

    // The current lightmap: RGB = combined, direct.* and indirect.* layers,
    // "samples" (indirect samples behind the value), "error" (standard error
    // of the texel's value), with settings.directional the L1x.*, L1y.*,
    // L1z.* layers (E(n')/pi ~ RGB + L1 . (n' - n), n the texel's normal);
    // dilated past chart borders. Uncovered texels are 0.
    FloatImage snapshot() const { return image(read_back()); }

    // snapshot() in two halves: reading the accumulators back (GL thread),
    // and making the image from them (any thread: reads only what the
    // constructor set).
    struct Readback {
        std::vector<glm::vec4> accumulators;
        std::vector<glm::vec4> directional;  // 3 per covered texel, with settings.directional
        PassStats stats;
    };
    Readback read_back() const;
    FloatImage image(const Readback& readback) const;

    // Resuming (bake/method_state.h): the accumulators, the L1 sums, the
    // texels still tracing, and inside a cell the map its passes read (the
    // pass count says where the epochs and cells are); restore()
    // publishes again what the next pass's indirect rays read, from the
    // restored accumulators at a cell's end.
    MethodState state() const;
    void restore(const MethodState& state);

    size_t covered_texels() const { return covered_count_; }
    // The first pass's rays, before any texel has converged (stats' rays also
    // count the bounces' extra rays).
    uint64_t rays_per_pass() const { return rays_per_texel_ * uint64_t(covered_count_); }
    // Texels next to intersecting geometry (a shelf through a wall, a stair
    // against one): those with a sample point moved out from inside or
    // behind a surface (texel_relocate.comp), and all those whose samples
    // were moved, or cut apart by a surface and kept to one side of it, or
    // that straddle a wall (texel_anchor.comp, texel_wall_check.comp; the
    // lookups test which side of the wall they see).
    size_t texels_moved_out_of_geometry() const { return moved_texels_; }
    size_t texels_cut_by_geometry() const { return cut_texels_; }

private:
    void upload_texels(const TexelSamples& texels);
    void bind_buffers() const;
    template <class Baker>
    static auto state_buffers(Baker& baker, bool with_map);
    // Whether `pass` passes end a cell (the map is the accumulators' values there).
    bool at_cell_end(int pass) const;
    // One dispatch of `count` passes from `first_pass`
    // (radiosity_gather.comp), each resolved as it ends, then their totals
    // summed per work group (radiosity_totals.comp) into partials slots
    // `slot` to `slot + count - 1`; `end_epoch`: the last one ends an epoch.
    RadiosityParams params() const;
    void dispatch_passes(int first_pass, int count, bool end_epoch, int slot);
    // Publishes the texels' values to the next passes' indirect rays (radiosity_publish.comp).
    void publish();
    struct ResolveTotals {
        double variance = 0.0, level = 0.0, active_next = 0.0, covered = 0.0, extra_rays = 0.0, unknown = 0.0;
    };
    // Sums one slot of partials read back (error_partials_).
    ResolveTotals totals_of(const std::vector<glm::vec4>& partials, int slot) const;
    // Counts a resolved pass into stats_ (rays, active texels, error).
    void count_pass(const ResolveTotals& totals);
    void relocate_samples_inside_geometry(size_t sample_count);
    void copy_to_dilated_texels(const GpuBuffer& atlas_buffer);
    void count_texels_by_geometry(const GpuBuffer& moved_samples);
    void add_directional_layers(FloatImage& image, const std::vector<glm::vec4>& sums) const;

    const Tracer& tracer_;
    RadiosityMapSettings settings_;
    int passes_per_dispatch_ = 1;
    int width_ = 0, height_ = 0;
    size_t covered_count_ = 0;
    uint64_t layout_ = 0;  // hash of which atlas texel, which samples each covered texel is
    size_t moved_texels_ = 0, cut_texels_ = 0;
    std::vector<uint32_t> covered_atlas_index_;
    std::vector<std::pair<uint32_t, uint32_t>> dilation_;  // (to, from) atlas indices

    ComputeProgram gather_;
    ComputeProgram totals_{"radiosity_totals.comp"};
    ComputeProgram publish_;
    ComputeProgram copy_{"copy_texels.comp"};
    SceneShading shading_;
    std::optional<SurfaceTextures> surface_textures_;  // the path-tracing scheme's exact textures
    GpuBuffer sample_points_, covered_, accumulators_, reflected_;
    GpuBuffer error_partials_, dilation_pairs_, texel_anchors_;
    GpuBuffer texel_totals_;  // per pass of a dispatch and covered texel: what it adds to the pass's totals
    // error_partials_ holds max_batch_ slots of partials_slot_bytes_ each, one per pass of a batch.
    size_t partials_slot_bytes_ = 0;
    int max_batch_ = 1;
    GpuTimestamps dispatch_ends_{0};  // mark 0 before a batch, mark k after its dispatch k
    GpuBuffer texel_albedo_;          // per atlas texel, dilated: what a final gather's hit reflects
    GpuBuffer reflected_indirect_;    // per atlas texel: albedo x the indirect layer (final gather only)
    GpuBuffer directional_;           // 3 vec4 per covered texel: L1 sums (settings.directional)

    PassStats stats_;
    uint64_t rays_per_texel_ = 0;
    size_t active_texels_ = 0;  // texels the next pass traces for
};

}  // namespace lf
