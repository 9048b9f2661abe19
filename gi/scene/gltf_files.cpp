#include "scene/gltf_files.h"

#include "percent_decoding.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>

namespace lf::gltf {

namespace {

// Reads a regular file of at most max_bytes into *out; false with the reason
// in *why otherwise. The size comes from fstat on the open descriptor, so the
// check and the read see the same file.
bool read_regular_file(const fs::path& path, uint64_t max_bytes, std::vector<unsigned char>* out, std::string* why) {
    // O_NONBLOCK: opening a FIFO must not wait for a writer; fstat below refuses it anyway.
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
    if (fd < 0) {
        *why = std::string("cannot be opened (") + std::strerror(errno) + ")";
        return false;
    }
    struct Closer {
        int fd;
        ~Closer() { ::close(fd); }
    } closer{fd};

    struct stat st {};
    if (::fstat(fd, &st) != 0) {
        *why = std::string("cannot be examined (") + std::strerror(errno) + ")";
        return false;
    }
    if (!S_ISREG(st.st_mode)) {
        *why = "is not a regular file";
        return false;
    }
    const uint64_t size = uint64_t(st.st_size);
    if (size > max_bytes) {
        *why = "is " + std::to_string(size) + " bytes, over the limit of " + std::to_string(max_bytes) + " bytes";
        return false;
    }

    out->resize(size_t(size));
    uint64_t done = 0;
    while (done < size) {
        const ssize_t n = ::read(fd, out->data() + done, size_t(size - done));
        if (n < 0 && errno == EINTR) continue;
        if (n < 0) {
            *why = std::string("cannot be read (") + std::strerror(errno) + ")";
            return false;
        }
        if (n == 0) break;  // the file shrank while we read it
        done += uint64_t(n);
    }
    out->resize(size_t(done));
    return true;
}

int hex_value(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

// The path string tinygltf builds for a URI: its JoinPath(base_dir,
// dlib::urldecode(uri)). Reproduced exactly (including the '+' -> ' ' of
// form decoding) so that its requests can be matched against approved files.
std::string tinygltf_request_path(const std::string& base_dir, std::string_view uri) {
    std::string decoded;
    for (size_t i = 0; i < uri.size(); ++i) {
        if (uri[i] == '+') {
            decoded += ' ';
        } else if (uri[i] == '%' && uri.size() > i + 2) {
            const int hi = std::max(hex_value(uri[i + 1]), 0);
            const int lo = std::max(hex_value(uri[i + 2]), 0);
            decoded += char((hi << 4) | lo);
            i += 2;
        } else {
            decoded += uri[i];
        }
    }
    if (base_dir.empty()) return decoded;
    return base_dir.back() == '/' ? base_dir + decoded : base_dir + "/" + decoded;
}

// True if `inner` is `outer` or lies below it (both canonical).
bool is_within(const fs::path& outer, const fs::path& inner) {
    auto o = outer.begin();
    auto i = inner.begin();
    for (; o != outer.end(); ++o, ++i) {
        if (i == inner.end() || *o != *i) return false;
    }
    return true;
}

}  // namespace

std::vector<unsigned char> read_file_limited(const fs::path& path, uint64_t max_bytes, const Errors& errors,
                                             const std::string& what) {
    std::vector<unsigned char> data;
    std::string why;
    if (!read_regular_file(path, max_bytes, &data, &why)) errors.fail(what.empty() ? why : what + ": " + why);
    return data;
}

// --- data: URIs ---------------------------------------------------------------

bool is_data_uri(std::string_view uri) {
    if (uri.size() < 5) return false;
    for (size_t i = 0; i < 5; ++i) {
        if (std::tolower(static_cast<unsigned char>(uri[i])) != "data:"[i]) return false;
    }
    return true;
}

std::string parse_data_uri(std::string_view uri, DataUri* out) {
    const size_t comma = uri.find(',');
    if (!is_data_uri(uri) || comma == std::string_view::npos) return "data: URI has no ',' before its data";
    std::string_view header = uri.substr(5, comma - 5);
    constexpr std::string_view kBase64 = ";base64";
    if (header.size() < kBase64.size() || header.substr(header.size() - kBase64.size()) != kBase64)
        return "data: URI is not base64-encoded";
    out->media_type = std::string(header.substr(0, header.size() - kBase64.size()));
    out->payload = uri.substr(comma + 1);
    return {};
}

bool base64_decoded_size(std::string_view payload, uint64_t* size, std::string* why) {
    if (payload.empty()) {
        *why = "data: URI holds no data";
        return false;
    }
    size_t padding = 0;
    for (size_t i = 0; i < payload.size(); ++i) {
        const unsigned char c = static_cast<unsigned char>(payload[i]);
        const bool alphabet = std::isalnum(c) || c == '+' || c == '/';
        if (c == '=' && i + 2 >= payload.size()) {
            ++padding;
            continue;
        }
        if (!alphabet || padding > 0) {
            *why = "data: URI is not valid base64 (character " + in_quotes(std::string(1, char(c))) + " at offset " +
                   std::to_string(i) + ")";
            return false;
        }
    }
    if (payload.size() % 4 != 0) {
        *why = "data: URI is not valid base64 (length " + std::to_string(payload.size()) + " is not a multiple of 4)";
        return false;
    }
    *size = uint64_t(payload.size() / 4) * 3 - padding;
    return true;
}

// --- relative URIs --------------------------------------------------------------

fs::path resolve_scene_file(const fs::path& scene_dir, std::string_view uri, std::string* why) {
    if (uri.empty()) {
        *why = "URI is empty";
        return {};
    }
    for (char c : uri) {
        const unsigned char u = static_cast<unsigned char>(c);
        if (u < 0x20 || u == 0x7f) {
            *why = "URI contains control characters";
            return {};
        }
        if (c == '\\') {
            *why = "URI contains a backslash";
            return {};
        }
        if (c == '?' || c == '#') {
            *why = "URI has a query or fragment";
            return {};
        }
    }
    // A ':' before the first '/' makes a scheme ("file:", "http:", "C:").
    const size_t colon = uri.find(':');
    if (colon != std::string_view::npos && colon < uri.find('/')) {
        *why = "URI has a scheme (only data: URIs and relative paths are allowed)";
        return {};
    }

    const std::optional<std::string> decoded_or = protocol::percent_decode(uri);
    if (!decoded_or) {
        *why = "URI has a malformed %-escape";
        return {};
    }
    const std::string& decoded = *decoded_or;
    if (decoded.find('\0') != std::string::npos || decoded.find('\\') != std::string::npos) {
        *why = "URI decodes to a NUL byte or a backslash";
        return {};
    }
    if (decoded.front() == '/') {
        *why = "URI is an absolute path";
        return {};
    }
    const fs::path relative = fs::path(decoded).lexically_normal();
    if (relative.empty() || relative.is_absolute() || *relative.begin() == "..") {
        *why = "URI leaves the scene directory";
        return {};
    }

    std::error_code ec;
    const fs::path full = fs::canonical(scene_dir / relative, ec);
    if (ec) {
        *why = "file not found in the scene directory";
        return {};
    }
    // Lexically inside, but a symlink may still point elsewhere.
    if (!is_within(scene_dir, full)) {
        *why = "URI leads outside the scene directory (through a symbolic link)";
        return {};
    }
    if (!fs::is_regular_file(full, ec)) {
        *why = "not a regular file";
        return {};
    }
    return full;
}

// --- the callbacks tinygltf reads through ----------------------------------------

SceneFiles::SceneFiles(fs::path scene_dir, uint64_t byte_budget)
    : scene_dir_(std::move(scene_dir)), base_dir_(scene_dir_.string()), budget_(byte_budget) {}

void SceneFiles::approve(std::string_view uri, const fs::path& resolved) {
    approved_[tinygltf_request_path(base_dir_, uri)] = resolved;
}

tinygltf::FsCallbacks SceneFiles::callbacks() {
    tinygltf::FsCallbacks callbacks{};
    callbacks.FileExists = &SceneFiles::file_exists;
    callbacks.ExpandFilePath = &SceneFiles::expand_file_path;
    callbacks.ReadWholeFile = &SceneFiles::read_whole_file;
    callbacks.WriteWholeFile = &SceneFiles::write_whole_file;
    callbacks.user_data = this;
    return callbacks;
}

bool SceneFiles::file_exists(const std::string& path, void* self) {
    return static_cast<SceneFiles*>(self)->approved_.count(path) != 0;
}

// Verbatim: no `~`, no `$VAR`, no `$(...)`. tinygltf's default runs wordexp here.
std::string SceneFiles::expand_file_path(const std::string& path, void*) { return path; }

bool SceneFiles::read_whole_file(std::vector<unsigned char>* out, std::string* err, const std::string& path,
                                 void* self_ptr) {
    SceneFiles& self = *static_cast<SceneFiles*>(self_ptr);
    const auto it = self.approved_.find(path);
    if (it == self.approved_.end()) {
        if (err) *err = "not a file of this scene";
        return false;
    }
    std::string why;
    if (!read_regular_file(it->second, self.budget_, out, &why)) {
        if (err) *err = why + " (remaining byte budget of the scene)";
        return false;
    }
    self.charge(*out);
    return true;
}

bool SceneFiles::write_whole_file(std::string* err, const std::string&, const std::vector<unsigned char>&, void*) {
    if (err) *err = "the scene loader never writes files";
    return false;
}

}  // namespace lf::gltf
