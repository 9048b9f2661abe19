#include "bake/sh_transfer_baker.h"

#include "gpu/context.h"
#include "shaders/buffer_bindings.glsl"
#include "util/stopwatch.h"

#include <glm/gtc/type_ptr.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>
#include <unordered_map>

namespace lf {

namespace {

bool contains(const std::vector<int>& set, int mesh) {
    return set.empty() || std::find(set.begin(), set.end(), mesh) != set.end();
}

// Vertices are the same when position and normal are bitwise equal: a
// glTF file splits vertices for UV seams and across primitives, and those
// copies see the same hemisphere.
struct VertexKey {
    uint32_t bits[6];
    bool operator==(const VertexKey& o) const { return std::memcmp(bits, o.bits, sizeof bits) == 0; }
};
struct VertexKeyHash {
    size_t operator()(const VertexKey& k) const {
        uint64_t h = 1469598103934665603ull;
        for (uint32_t b : k.bits) h = (h ^ b) * 1099511628211ull;
        return size_t(h);
    }
};

VertexKey key_of(glm::vec3 p, glm::vec3 n) {
    VertexKey k;
    const float f[6] = {p.x, p.y, p.z, n.x, n.y, n.z};
    for (int i = 0; i < 6; ++i) {
        std::memcpy(&k.bits[i], &f[i], 4);
        if ((k.bits[i] & 0x7fffffffu) == 0) k.bits[i] = 0;  // -0 == +0
    }
    return k;
}

}  // namespace

ShTransferBaker::ShTransferBaker(const Scene& scene, const Tracer& tracer, const ShTransferSettings& settings,
                                 const std::vector<ShReceiverPoint>& points)
    : scene_(scene),
      settings_(settings),
      tracer_(&tracer),
      // Built for the whole scene: the occluders' own tracer (build_occluders)
      // has no see-through surface the scene lacks.
      transfer_(tracer.program("sh_transfer.comp", {{"LF_SH_BOUNCES", std::to_string(settings.bounces)}})),
      resolve_("sh_resolve.comp", {{"LF_SH_BOUNCES", std::to_string(settings.bounces)}}) {
    if (settings_.samples_per_pass < 1) throw std::invalid_argument("SH transfer: samples per pass must be >= 1");
    if (settings_.bounces < 0 || settings_.bounces > ShTransferSettings::kMaxBounces)
        throw std::invalid_argument("SH transfer: bounces must be 0.." +
                                    std::to_string(ShTransferSettings::kMaxBounces) + ", not " +
                                    std::to_string(settings_.bounces));
    if (settings_.near < 0.0f || settings_.far < 0.0f || (settings_.far > 0.0f && settings_.far <= settings_.near))
        throw std::invalid_argument("SH transfer: need 0 <= near < far (far 0 = unlimited)");
    build_receivers(scene, points);
    build_occluders(scene);
    software_renderer_ = renderer_is_software();
}

ShTransferBaker::~ShTransferBaker() = default;

void ShTransferBaker::build_receivers(const Scene& scene, const std::vector<ShReceiverPoint>& points) {
    // Receivers first (vertices, then the extra points), so a pass dispatches
    // over 0 .. receiver_count_-1.
    std::vector<bool> receives(scene.positions.size(), false);
    for (const PrimitiveInstance& inst : scene.instances)
        if (contains(settings_.receiver_meshes, inst.mesh))
            for (uint32_t k = 0; k < inst.vertex_count; ++k) receives[inst.first_vertex + k] = true;

    std::unordered_map<VertexKey, uint32_t, VertexKeyHash> seen;
    unique_of_vertex_.assign(scene.positions.size(), 0);
    std::vector<glm::vec4> data;
    std::vector<uint32_t> pending;  // non-receivers, numbered after all receivers
    for (int pass = 0; pass < 2; ++pass) {
        for (size_t v = 0; v < scene.positions.size(); ++v) {
            if (receives[v] != (pass == 0)) continue;
            const glm::vec3 n = glm::normalize(scene.normals[v]);
            auto [it, fresh] = seen.try_emplace(key_of(scene.positions[v], n), uint32_t(unique_normal_.size()));
            unique_of_vertex_[v] = it->second;
            if (!fresh) continue;
            unique_normal_.push_back(n);
            data.push_back(glm::vec4(scene.positions[v], 0.0f));
            data.push_back(glm::vec4(n, 0.0f));
        }
        if (pass == 0) {
            receiver_vertex_count_ = unique_normal_.size();
            for (const ShReceiverPoint& r : points) {
                const glm::vec3 n = glm::normalize(r.normal);
                unique_normal_.push_back(n);
                data.push_back(glm::vec4(r.position, 0.0f));
                data.push_back(glm::vec4(n, 0.0f));
            }
            point_count_ = points.size();
            receiver_count_ = unique_normal_.size();
        }
    }
    unique_count_ = unique_normal_.size();
    vertices_ = GpuBuffer(data);

    const size_t blocks = size_t(settings_.bounces) + 1;
    accum_ = GpuBuffer(unique_count_ * 4 * (blocks + 1) * sizeof(glm::vec4));
    accum_.clear_zero();
    // Non-receivers keep the unoccluded transfer of their normal in block 0
    // (what a bounce off them reflects); the resolve pass never touches them.
    std::vector<glm::vec4> resolved(unique_count_ * 4 * blocks, glm::vec4(0.0f));
    for (size_t u = receiver_count_; u < unique_count_; ++u) {
        const ShCoefficients t = unoccluded_transfer(unique_normal_[u]);
        for (int c = 0; c < 4; ++c) resolved[u * 4 * blocks + size_t(c)] = glm::make_vec4(&t[4 * c]);
    }
    resolved_ = GpuBuffer(resolved);
    // One vec4 per work group of the resolve pass, however it is dispatched.
    error_partials_ = GpuBuffer(std::max<size_t>(1, resolve_.groups_1d(receiver_count_)) * sizeof(glm::vec4));
}

void ShTransferBaker::build_occluders(const Scene& scene) {
    // Which triangles cast: the occluder meshes' (all by default).
    std::vector<uint32_t> occluders;
    for (const PrimitiveInstance& inst : scene.instances)
        if (contains(settings_.occluder_meshes, inst.mesh))
            for (uint32_t t = 0; t < inst.triangle_count; ++t) occluders.push_back(inst.first_triangle + t);
    std::sort(occluders.begin(), occluders.end());
    if (!settings_.occluder_meshes.empty()) {
        // A BVH of the occluders alone; its triangle indices count occluders.
        // (Materials, textures and UVs as the scene's: see-through occluders pass light.)
        Scene subset;
        subset.positions = scene.positions;
        subset.uv0 = scene.uv0;
        subset.materials = scene.materials;
        subset.textures = scene.textures;
        for (uint32_t t : occluders) {
            subset.triangles.push_back(scene.triangles[t]);
            subset.triangle_material.push_back(scene.triangle_material[t]);
        }
        own_tracer_ = std::make_unique<Tracer>(subset);
        tracer_ = own_tracer_.get();
    } else {
        occluders.resize(scene.triangles.size());
        for (size_t t = 0; t < occluders.size(); ++t) occluders[t] = uint32_t(t);
    }
    if (settings_.bounces == 0) return;

    // What a bounce reads where a ray lands: the corners' unique vertices and
    // their albedo (RGB channel mean: transfer is one channel; textures sampled at the corners).
    std::vector<glm::uvec4> ids(std::max<size_t>(occluders.size(), 1), glm::uvec4(0u));
    std::vector<glm::vec4> albedo(ids.size(), glm::vec4(0.0f));
    for (size_t k = 0; k < occluders.size(); ++k) {
        const uint32_t t = occluders[k];
        const glm::uvec3 tri = scene.triangles[t];
        ids[k] = glm::uvec4(unique_of_vertex_[tri.x], unique_of_vertex_[tri.y], unique_of_vertex_[tri.z], 0u);
        const glm::vec2 corners[3] = {{0.0f, 0.0f}, {1.0f, 0.0f}, {0.0f, 1.0f}};
        for (int c = 0; c < 3; ++c) {
            const glm::vec3 a = scene.albedo_at(t, corners[c]);
            albedo[k][c] = (a.r + a.g + a.b) / 3.0f;
        }
    }
    triangle_ids_ = GpuBuffer(ids);
    triangle_albedo_ = GpuBuffer(albedo);
}

PassStats ShTransferBaker::step() {
    const Stopwatch clock;
    tracer_->bind();
    vertices_.bind(LF_BINDING_SH_VERTICES);
    accum_.bind(LF_BINDING_SH_ACCUMULATORS);
    resolved_.bind(LF_BINDING_SH_RESOLVED);
    if (settings_.bounces > 0) {
        triangle_ids_.bind(LF_BINDING_SH_TRIANGLE_IDS);
        triangle_albedo_.bind(LF_BINDING_SH_TRIANGLE_ALBEDO);
    }
    error_partials_.bind(LF_BINDING_SH_ERROR_PARTIALS);

    ShTransferParams params{};
    params.vertex_count = uint32_t(receiver_count_);
    params.pass = uint32_t(stats_.pass);
    params.samples_per_pass = uint32_t(settings_.samples_per_pass);
    params.seed = settings_.seed;
    params.near_dist = settings_.near;
    params.far_dist = settings_.far > 0.0f ? settings_.far - settings_.near : 1e30f;
    // A pass in slices of samples: Mesa's llvmpipe ends a shader invocation
    // after 65535 loop iterations in all (LP_MAX_TGSI_LOOP_ITERATIONS), BVH
    // traversal steps included, and silently drops the rest; a GPU takes the
    // whole pass in one dispatch.
    const int slice = software_renderer_ ? std::min(settings_.samples_per_pass, 16) : settings_.samples_per_pass;
    for (int first = 0; first < settings_.samples_per_pass; first += slice) {
        params.sample_first = uint32_t(first);
        params.sample_count = uint32_t(std::min(slice, settings_.samples_per_pass - first));
        transfer_.use(params);
        transfer_.dispatch_1d(receiver_count_);
        glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    }
    ++stats_.pass;

    params.pass = uint32_t(stats_.pass);  // passes done: the rays behind each block (sh_resolve.comp)
    resolve_.use(params);
    resolve_.dispatch_1d(receiver_count_);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    check_gl("sh transfer pass");

    // Reading the error totals back also waits for the pass to finish.
    double variance = 0.0, level = 0.0;
    for (const glm::vec4& p : error_partials_.read<glm::vec4>()) {
        variance += p.x;
        level += p.y;
    }
    stats_.rays += uint64_t(receiver_count_) * uint64_t(settings_.samples_per_pass);
    stats_.seconds += clock.seconds();
    stats_.error_estimate = level > 0.0 ? std::sqrt(variance / level) : 0.0;
    return stats_;
}

uint64_t ShTransferBaker::layout() const {
    const std::vector<uint64_t> counts = {unique_count_, receiver_count_, receiver_vertex_count_, point_count_};
    return hash_vector(counts, hash_vector(unique_of_vertex_));
}

MethodState ShTransferBaker::state() const {
    MethodState s;
    s.layout = layout();
    s.stats = stats_;
    s.buffers = {buffer_bytes(accum_), buffer_bytes(resolved_)};
    return s;
}

void ShTransferBaker::restore(const MethodState& s) {
    if (s.layout != layout()) throw MethodStateMismatch("the SH receivers are laid out differently");
    restore_buffers({{&accum_, "the receivers' running sums"}, {&resolved_, "the receivers' transfer"}}, s.buffers);
    stats_ = s.stats;
}

ShVertexTransfer ShTransferBaker::snapshot() const {
    const size_t blocks = size_t(settings_.bounces) + 1;
    const std::vector<float> resolved = resolved_.read<float>();
    const std::vector<float> accum = accum_.read<float>();
    const double n = double(stats_.pass) * settings_.samples_per_pass;

    std::vector<ShCoefficients> total(unique_count_), error(unique_count_);
    for (size_t u = 0; u < unique_count_; ++u) {
        ShCoefficients t{}, e{};
        for (size_t k = 0; k < blocks; ++k)
            for (int i = 0; i < kShMaxCoefficients; ++i)
                t[i] += resolved[(u * blocks + k) * kShMaxCoefficients + size_t(i)];
        if (u < receiver_count_ && n > 1.0) {
            const size_t squares = (u * (blocks + 1) + blocks) * kShMaxCoefficients;
            for (int i = 0; i < kShMaxCoefficients; ++i) {
                const double second = accum[squares + size_t(i)] / n;
                e[i] = float(std::sqrt(std::max(0.0, second - double(t[i]) * t[i]) / (n - 1.0)));
            }
        }
        total[u] = t;
        error[u] = e;
    }
    ShVertexTransfer out;
    out.point_coefficients.assign(total.begin() + std::ptrdiff_t(receiver_vertex_count_),
                                  total.begin() + std::ptrdiff_t(receiver_count_));
    out.point_standard_error.assign(error.begin() + std::ptrdiff_t(receiver_vertex_count_),
                                    error.begin() + std::ptrdiff_t(receiver_count_));
    out.coefficients.resize(unique_of_vertex_.size());
    out.standard_error.resize(unique_of_vertex_.size());
    out.traced.resize(unique_of_vertex_.size());
    for (size_t v = 0; v < unique_of_vertex_.size(); ++v) {
        const uint32_t u = unique_of_vertex_[v];
        out.coefficients[v] = total[u];
        out.standard_error[v] = error[u];
        out.traced[v] = u < receiver_count_;
    }
    return out;
}

}  // namespace lf
