#include "gpu/shader.h"

#include "gpu/context.h"
#include "gpu/embedded_shaders.h"
#include "shaders/buffer_bindings.glsl"

#include <glm/packing.hpp>
#include <glm/vec2.hpp>
#include <glm/common.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <regex>
#include <set>
#include <sstream>

namespace lf {

namespace {

const std::string& embedded_source(const std::string& name, const std::string& included_from) {
    static std::map<std::string, std::string> cache;
    auto cached = cache.find(name);
    if (cached != cache.end()) return cached->second;
    const auto& all = embedded_shaders();
    auto it = all.find(name);
    if (it == all.end())
        throw GpuError("shader '" + name + "' not found among the embedded shaders" +
                       (included_from.empty() ? "" : " (included from " + included_from + ")"));
    return cache.emplace(name, std::string(it->second)).first->second;
}

void append_with_includes(const std::string& name, const std::string& from, std::string& out,
                          std::vector<std::string>& files, std::set<std::string>& seen) {
    if (!seen.insert(name).second) return;  // each file once: includes act as if guarded
    const std::string& text = embedded_source(name, from);
    const size_t file_number = files.size();
    files.push_back(name);
    static const std::regex include_re(R"(^\s*#\s*include\s+"([^"]+)\"\s*$)");
    std::istringstream lines(text);
    std::string line;
    int line_number = 0;
    if (file_number > 0) out += "#line 1 " + std::to_string(file_number) + "\n";
    while (std::getline(lines, line)) {
        ++line_number;
        std::smatch m;
        if (std::regex_match(line, m, include_re)) {
            append_with_includes(m[1], name, out, files, seen);
            out += "#line " + std::to_string(line_number + 1) + " " + std::to_string(file_number) + "\n";
        } else {
            out += line;
            out += '\n';
        }
    }
}

// Turns the driver's "N:LINE(COL)" / "N(LINE)" prefixes into a readable
// listing of which number is which file.
std::string file_legend(const std::vector<std::string>& files) {
    std::string s = " [source numbers:";
    for (size_t i = 0; i < files.size(); ++i) s += " " + std::to_string(i) + "=" + files[i];
    return s + "]";
}

}  // namespace

std::pair<std::string, std::vector<std::string>> assemble_shader_source(const std::string& name,
                                                                        const ShaderDefines& defines) {
    std::string body;
    std::vector<std::string> files;
    std::set<std::string> seen;
    append_with_includes(name, "", body, files, seen);
    // The #version line must come first; defines go right after it.
    std::string version = "#version 450 core\n";
    const size_t v = body.find("#version");
    if (v != std::string::npos) {
        const size_t end = body.find('\n', v);
        version = body.substr(v, end - v + 1);
        body.erase(v, end - v + 1);
    }
    std::string out = version;
    for (const auto& [key, value] : defines) out += "#define " + key + " " + value + "\n";
    out += "#line 1 0\n" + body;
    return {out, files};
}

ComputeProgram::ComputeProgram(const std::string& name, const ShaderDefines& defines) : name_(name) {
    auto [source, files] = assemble_shader_source(name, defines);
    GLuint shader = glCreateShader(GL_COMPUTE_SHADER);
    const char* text = source.c_str();
    glShaderSource(shader, 1, &text, nullptr);
    glCompileShader(shader);
    GLint ok = 0;
    glGetShaderiv(shader, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        GLint length = 0;
        glGetShaderiv(shader, GL_INFO_LOG_LENGTH, &length);
        std::string log(size_t(std::max(length, 1)), '\0');
        glGetShaderInfoLog(shader, length, nullptr, log.data());
        glDeleteShader(shader);
        throw GpuError("compiling " + name + " failed" + file_legend(files) + ": " + log.c_str());
    }
    id_ = glCreateProgram();
    glAttachShader(id_, shader);
    glLinkProgram(id_);
    glDeleteShader(shader);
    glGetProgramiv(id_, GL_LINK_STATUS, &ok);
    if (!ok) {
        GLint length = 0;
        glGetProgramiv(id_, GL_INFO_LOG_LENGTH, &length);
        std::string log(size_t(std::max(length, 1)), '\0');
        glGetProgramInfoLog(id_, length, nullptr, log.data());
        glDeleteProgram(id_);
        id_ = 0;
        throw GpuError("linking " + name + " failed: " + log.c_str());
    }
    GLint size[3] = {1, 1, 1};
    glGetProgramiv(id_, GL_COMPUTE_WORK_GROUP_SIZE, size);
    local_size_x_ = size[0];
    read_parameter_block();
}

// Finds the program's parameter block (LF_BINDING_PARAMS), and refuses a
// uniform outside it: every value a dispatch takes goes through use(params).
// The one exception is a buffer texture (the environment's texels,
// environment.glsl): a binding, not a value.
void ComputeProgram::read_parameter_block() {
    GLint blocks = 0, uniforms = 0;
    glGetProgramiv(id_, GL_ACTIVE_UNIFORM_BLOCKS, &blocks);
    for (GLuint b = 0; b < GLuint(blocks); ++b) {
        GLint binding = -1, bytes = 0;
        glGetActiveUniformBlockiv(id_, b, GL_UNIFORM_BLOCK_BINDING, &binding);
        glGetActiveUniformBlockiv(id_, b, GL_UNIFORM_BLOCK_DATA_SIZE, &bytes);
        if (binding == LF_BINDING_PARAMS) params_bytes_ = size_t(bytes);
    }
    glGetProgramiv(id_, GL_ACTIVE_UNIFORMS, &uniforms);
    for (GLuint u = 0; u < GLuint(uniforms); ++u) {
        GLint block = -1;
        GLint type = 0;
        glGetActiveUniformsiv(id_, 1, &u, GL_UNIFORM_BLOCK_INDEX, &block);
        glGetActiveUniformsiv(id_, 1, &u, GL_UNIFORM_TYPE, &type);
        if (block != -1 || type == GL_SAMPLER_BUFFER) continue;
        char uniform_name[128] = {};
        glGetActiveUniformName(id_, u, sizeof uniform_name, nullptr, uniform_name);
        glDeleteProgram(id_);  // the constructor throws: no destructor will
        id_ = 0;
        throw GpuError(name_ + ": uniform '" + uniform_name +
                       "' is outside the parameter block (a *_params.glsl field, set by use(params))");
    }
}

void ComputeProgram::set_params(const void* data, size_t bytes) const {
    if (params_bytes_ == 0) return;  // the program reads none of them
    // std140 rounds a block up to 16 bytes; the C++ struct need not be.
    if ((bytes + 15) / 16 * 16 != params_bytes_)
        throw GpuError(name_ + ": its parameter block is " + std::to_string(params_bytes_) + " bytes, the C++ struct " +
                       std::to_string(bytes));
    if (params_.bytes() == 0) params_ = GpuBuffer(params_bytes_);
    params_.upload(data, bytes);
    glBindBufferBase(GL_UNIFORM_BUFFER, LF_BINDING_PARAMS, params_.id());
}

ComputeProgram::~ComputeProgram() {
    if (id_) glDeleteProgram(id_);
}

namespace {
// GL guarantees at least 65535 work groups per dimension.
constexpr size_t kMaxGroupsX = 65535;
}  // namespace

size_t ComputeProgram::groups_1d(size_t n) const {
    const size_t groups = (n + size_t(local_size_x_) - 1) / size_t(local_size_x_);
    const size_t gy = (groups + kMaxGroupsX - 1) / kMaxGroupsX;
    return std::min(groups, kMaxGroupsX) * gy;
}

void ComputeProgram::dispatch_1d(size_t n) const {
    if (n == 0) return;
    const size_t groups = (n + size_t(local_size_x_) - 1) / size_t(local_size_x_);
    const GLuint gx = GLuint(std::min(groups, kMaxGroupsX));
    const GLuint gy = GLuint((groups + kMaxGroupsX - 1) / kMaxGroupsX);
    glDispatchCompute(gx, gy, 1);
    check_gl(name_.c_str());
}

float pack_unit_vector(glm::vec3 v) {
    const float l1 = std::abs(v.x) + std::abs(v.y) + std::abs(v.z);
    // No direction (a degenerate triangle's normal), or not a number: +z,
    // a unit vector rather than whatever NaN would pack to.
    if (!(l1 > 0.0f) || !std::isfinite(l1)) return uint_bits(glm::packSnorm2x16(glm::vec2(0.0f)));
    v /= l1;
    glm::vec2 e(v.x, v.y);
    if (v.z < 0.0f)  // the lower half folded over the diagonals
        e = (1.0f - glm::abs(glm::vec2(v.y, v.x))) * glm::vec2(v.x >= 0.0f ? 1.0f : -1.0f, v.y >= 0.0f ? 1.0f : -1.0f);
    return uint_bits(glm::packSnorm2x16(e));
}

GpuBuffer::GpuBuffer(size_t bytes, const void* data) : bytes_(bytes) {
    if (bytes > kMaxGpuBufferBytes) {
        char text[128];
        std::snprintf(text, sizeof text, "a GPU buffer of %.2f GB, more than the %.2f GB a shader can address in one",
                      double(bytes) / 1e9, double(kMaxGpuBufferBytes) / 1e9);
        throw GpuBufferTooLarge(text);
    }
    glCreateBuffers(1, &id_);
    // Zero-sized SSBOs are not allowed; keep a 16-byte minimum so empty inputs still bind.
    glNamedBufferStorage(id_, GLsizeiptr(std::max<size_t>(bytes, 16)), bytes ? data : nullptr, GL_DYNAMIC_STORAGE_BIT);
    check_gl("allocating a GPU buffer");
}

GpuBuffer::~GpuBuffer() {
    if (id_) glDeleteBuffers(1, &id_);
}

GpuBuffer& GpuBuffer::operator=(GpuBuffer&& o) noexcept {
    if (this != &o) {
        if (id_) glDeleteBuffers(1, &id_);
        id_ = std::exchange(o.id_, 0);
        bytes_ = std::exchange(o.bytes_, 0);
    }
    return *this;
}

void GpuBuffer::upload(const void* data, size_t bytes, size_t offset) {
    glNamedBufferSubData(id_, GLintptr(offset), GLsizeiptr(bytes), data);
}

void GpuBuffer::download(void* data, size_t bytes, size_t offset) const {
    glMemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    glGetNamedBufferSubData(id_, GLintptr(offset), GLsizeiptr(bytes), data);
}

void GpuBuffer::clear_zero() { glClearNamedBufferData(id_, GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, nullptr); }

bool renderer_is_software() {
    const char* renderer = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
    return renderer && (std::strstr(renderer, "llvmpipe") || std::strstr(renderer, "softpipe"));
}

size_t storage_offset_alignment() {
    GLint alignment = 0;
    glGetIntegerv(GL_SHADER_STORAGE_BUFFER_OFFSET_ALIGNMENT, &alignment);
    return size_t(std::max(alignment, 1));
}

GpuTimestamps::GpuTimestamps(int count) : ids_(size_t(std::max(count, 0))) {
    if (!ids_.empty()) glGenQueries(GLsizei(ids_.size()), ids_.data());
}

GpuTimestamps::~GpuTimestamps() {
    if (!ids_.empty()) glDeleteQueries(GLsizei(ids_.size()), ids_.data());
}

GpuTimestamps& GpuTimestamps::operator=(GpuTimestamps&& o) noexcept {
    if (this != &o) {
        if (!ids_.empty()) glDeleteQueries(GLsizei(ids_.size()), ids_.data());
        ids_ = std::exchange(o.ids_, {});
    }
    return *this;
}

double GpuTimestamps::seconds(int i) const {
    GLuint64 from = 0, to = 0;
    glGetQueryObjectui64v(ids_[0], GL_QUERY_RESULT, &from);
    glGetQueryObjectui64v(ids_[size_t(i)], GL_QUERY_RESULT, &to);
    return to > from ? double(to - from) * 1e-9 : 0.0;
}

}  // namespace lf
