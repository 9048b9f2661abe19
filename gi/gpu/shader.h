// Compute programs built from the embedded GLSL files, and the GPU buffers
// they read and write.
#pragma once

#include <epoxy/gl.h>

#include "gpu/context.h"

#include <glm/vec3.hpp>

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <type_traits>
#include <string>
#include <utility>
#include <vector>

namespace lf {

// Compile-time choices, `#define NAME VALUE` each, inserted after #version.
using ShaderDefines = std::vector<std::pair<std::string, std::string>>;

// Resolves `#include "name.glsl"` against the embedded shaders (each file at
// most once) and inserts `#define`s after the #version line. Each file gets a
// `#line 1 N` so the driver's messages can be mapped back to file names.
// Returns the source and the file names in source-string-number order.
std::pair<std::string, std::vector<std::string>> assemble_shader_source(const std::string& name,
                                                                        const ShaderDefines& defines);

// A uint stored in a float lane of a vec4 buffer, read back in GLSL with
// floatBitsToUint (flags, indices, chart ids).
inline float uint_bits(uint32_t u) {
    float f;
    std::memcpy(&f, &u, sizeof f);
    return f;
}

// The most bytes one GpuBuffer holds. A shader indexes a storage buffer's
// bytes with 32-bit signed offsets on llvmpipe: the staircase's 4096² atlas,
// whose sample points took 2.26 GB in one buffer, crashed its worker there
// (2026-11-26). A buffer this large is refused with GpuBufferTooLarge
// instead, on every device, so that a bake's limits do not depend on the
// driver.
constexpr size_t kMaxGpuBufferBytes = (size_t(1) << 31) - 1;

// A buffer larger than kMaxGpuBufferBytes was asked for; what() says how large.
class GpuBufferTooLarge : public GpuError {
public:
    using GpuError::GpuError;
};

// A unit vector as two snorm16 octahedral coordinates in a float lane's
// bits (32 bits for 96), read in GLSL by unit_vector.glsl's
// lf_unpack_unit_vector. A zero or non-finite vector packs as +z.
float pack_unit_vector(glm::vec3 v);

// A shader storage buffer that owns its GL name.
class GpuBuffer {
public:
    GpuBuffer() = default;
    // Throws GpuBufferTooLarge above kMaxGpuBufferBytes.
    explicit GpuBuffer(size_t bytes, const void* data = nullptr);
    template <class T>
    explicit GpuBuffer(const std::vector<T>& v) : GpuBuffer(v.size() * sizeof(T), v.data()) {}
    ~GpuBuffer();
    GpuBuffer(GpuBuffer&& o) noexcept : id_(std::exchange(o.id_, 0)), bytes_(std::exchange(o.bytes_, 0)) {}
    GpuBuffer& operator=(GpuBuffer&& o) noexcept;
    GpuBuffer(const GpuBuffer&) = delete;
    GpuBuffer& operator=(const GpuBuffer&) = delete;

    void bind(GLuint binding) const { glBindBufferBase(GL_SHADER_STORAGE_BUFFER, binding, id_); }
    // Binds `bytes` from `offset`, which must be a multiple of storage_offset_alignment().
    void bind_range(GLuint binding, size_t offset, size_t bytes) const {
        glBindBufferRange(GL_SHADER_STORAGE_BUFFER, binding, id_, GLintptr(offset), GLsizeiptr(bytes));
    }
    void upload(const void* data, size_t bytes, size_t offset = 0);
    void download(void* data, size_t bytes, size_t offset = 0) const;
    template <class T>
    std::vector<T> read() const {
        std::vector<T> v(bytes_ / sizeof(T));
        download(v.data(), v.size() * sizeof(T));
        return v;
    }
    void clear_zero();
    size_t bytes() const { return bytes_; }
    GLuint id() const { return id_; }

private:
    GLuint id_ = 0;
    size_t bytes_ = 0;
};

class ComputeProgram {
public:
    // Compiles and links the embedded file `name`; a compile or link failure
    // throws GpuError with the file name and the driver's log.
    explicit ComputeProgram(const std::string& name, const ShaderDefines& defines = {});
    ~ComputeProgram();
    ComputeProgram(ComputeProgram&& other) noexcept
        : id_(std::exchange(other.id_, 0)),
          name_(std::move(other.name_)),
          local_size_x_(other.local_size_x_),
          params_bytes_(other.params_bytes_),
          params_(std::move(other.params_)) {}
    ComputeProgram(const ComputeProgram&) = delete;
    ComputeProgram& operator=(const ComputeProgram&) = delete;

    // Makes this the current program with the parameters of its next
    // dispatch: `params` is the C++ side of the program's parameter block
    // (its *_params.glsl, defined once for both languages), uploaded whole
    // and bound at LF_BINDING_PARAMS. A struct whose size is not the
    // block's throws GpuError naming the program (a field added on one side
    // only), where a uniform set by a misspelt name was silently ignored.
    template <class Params>
    void use(const Params& params) const {
        static_assert(std::is_trivially_copyable_v<Params>);
        use();
        set_params(&params, sizeof params);
    }
    void use() const { glUseProgram(id_); }
    // Dispatches groups_1d(n) groups for 1D work of n items: ceil(n /
    // local_size_x) in x up to GL's guaranteed 65535, spilling into y beyond.
    // Shaders index items as x + y * gl_NumWorkGroups.x * local_size_x and
    // skip those >= n; a per-group buffer must hold groups_1d(n) entries (the
    // spill rounds the group count up to a whole row of 65535).
    void dispatch_1d(size_t n) const;
    size_t groups_1d(size_t n) const;
    GLuint id() const { return id_; }
    const std::string& name() const { return name_; }

private:
    void read_parameter_block();
    void set_params(const void* data, size_t bytes) const;

    GLuint id_ = 0;
    std::string name_;
    GLint local_size_x_ = 1;
    size_t params_bytes_ = 0;   // the parameter block's size; 0 where the program reads none
    mutable GpuBuffer params_;  // made on the first use(params)
};

// What bind_range's offsets must be multiples of (GL_SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT).
size_t storage_offset_alignment();

// Whether the current context renders in software (Mesa's llvmpipe or
// softpipe): its "device" is the CPU's cores, which any pass fills.
bool renderer_is_software();

// Timestamps the device takes where it reaches them in the command stream
// (GL_TIMESTAMP queries): the times of the passes of a batch that the CPU
// waits for only at its end.
class GpuTimestamps {
public:
    explicit GpuTimestamps(int count);
    ~GpuTimestamps();
    GpuTimestamps(GpuTimestamps&& o) noexcept : ids_(std::exchange(o.ids_, {})) {}
    GpuTimestamps& operator=(GpuTimestamps&& o) noexcept;
    GpuTimestamps(const GpuTimestamps&) = delete;
    GpuTimestamps& operator=(const GpuTimestamps&) = delete;

    void mark(int i) const { glQueryCounter(ids_[size_t(i)], GL_TIMESTAMP); }
    // Seconds from mark 0 to mark i; waits until the device has passed mark i.
    double seconds(int i) const;

private:
    std::vector<GLuint> ids_;
};

}  // namespace lf
