// Preparation's time left, from the scene's size: what the "prepare" events
// say while a job loads, makes its atlas and sets its methods up, before its
// first pass (issue #36: a staircase prepared for 19-48 s, a 4096² atlas for
// minutes, and nothing was said meanwhile).
//
// Each stage's seconds are predicted from the sizes known when it starts
// (the file's bytes before loading; triangles once loaded; sample points
// once the atlas is made), with per-unit costs measured on llvmpipe (2 CPU
// cores, 2026-11-27; docs/BENCHMARKS.md "Preparation"). The machine at hand
// is faster or slower: once a second of preparation has passed, the
// prediction of what is left is scaled by how the stages done so far
// compared with theirs.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace lf {

// What the job's preparation is made of, in the order it runs.
struct PreparationSize {
    uint64_t scene_bytes = 0;             // the glTF and its buffers: all that is known before loading
    uint64_t triangles = 0;               // 0: not loaded yet (guessed from the bytes)
    uint64_t double_sided_triangles = 0;  // of double-sided materials: their charts are traced to turn them
    uint64_t sample_points = 0;           // the atlas's texel sample points; 0: not made yet (guessed)
    bool see_through = false;             // a material lets light through: llvmpipe traces at about half speed
    bool atlas = false;                   // a per-texel output: atlas, texel samples, relocation
    int outputs = 1;
};

class PreparationEstimate {
public:
    explicit PreparationEstimate(const PreparationSize& size) : size_(size) {}
    // Sizes learnt on the way.
    void set_triangles(uint64_t triangles, uint64_t double_sided, bool see_through) {
        size_.triangles = triangles;
        size_.double_sided_triangles = double_sided;
        size_.see_through = see_through;
    }
    void set_sample_points(uint64_t points) { size_.sample_points = points; }
    bool knows_triangles() const { return size_.triangles > 0; }

    // The stages still to run, `stage` first, and their predicted seconds.
    std::vector<std::pair<std::string, double>> stages_from(const std::string& stage) const;
    // Seconds left as `stage` begins, `elapsed` seconds into preparation, the
    // stages before it done; empty for a stage this estimate does not know.
    std::optional<double> seconds_left(const std::string& stage, double elapsed) const;

private:
    double predicted(const std::string& stage) const;

    PreparationSize size_;
};

}  // namespace lf
