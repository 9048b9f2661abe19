#include "scene_store.h"

#include "data_dir.h"
#include "hash.h"
#include "percent_decoding.h"
#include "http_error.h"
#include "log.h"
#include "subprocess.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>

namespace lf::server {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// Whether `text` is well-formed UTF-8 without the characters that make a
// name read other than it is: bidirectional controls (U+061C, U+200E,
// U+200F, U+202A..U+202E, U+2066..U+2069: "gpj.exe" shown as "exe.jpg").
std::string text_reason(const std::string& text) {
    for (size_t i = 0; i < text.size();) {
        const unsigned char c = static_cast<unsigned char>(text[i]);
        const int extra = c < 0x80 ? 0 : (c >> 5) == 6 ? 1 : (c >> 4) == 14 ? 2 : (c >> 3) == 30 ? 3 : -1;
        if (extra < 0 || text.size() - i <= size_t(extra)) return "is not UTF-8";
        uint32_t code = extra == 0 ? c : c & (0x3f >> extra);
        for (int k = 1; k <= extra; ++k) {
            const unsigned char next = static_cast<unsigned char>(text[i + size_t(k)]);
            if ((next >> 6) != 2) return "is not UTF-8";
            code = (code << 6) | (next & 0x3f);
        }
        if (code == 0x061c || code == 0x200e || code == 0x200f || (code >= 0x202a && code <= 0x202e) ||
            (code >= 0x2066 && code <= 0x2069))
            return "contains a bidirectional-text control character (U+" + [&] {
                char hex[8];
                std::snprintf(hex, sizeof hex, "%04X", code);
                return std::string(hex);
            }() + "), which makes a name read other than it is";
        i += size_t(extra) + 1;
    }
    return "";
}

}  // namespace

std::string shown_name(const std::string& name) {
    std::string out;
    for (size_t i = 0; i < name.size();) {
        const unsigned char c = static_cast<unsigned char>(name[i]);
        const int extra = c < 0x80 ? 0 : (c >> 5) == 6 ? 1 : (c >> 4) == 14 ? 2 : (c >> 3) == 30 ? 3 : -1;
        bool whole = extra >= 0 && name.size() - i > size_t(extra);
        for (int k = 1; whole && k <= extra; ++k) whole = (static_cast<unsigned char>(name[i + size_t(k)]) >> 6) == 2;
        if (!whole || c < 0x20 || c == 0x7f) {
            char hex[8];
            std::snprintf(hex, sizeof hex, "\\x%02X", c);
            out += hex;
            ++i;
            continue;
        }
        out.append(name, i, size_t(extra) + 1);
        i += size_t(extra) + 1;
    }
    return out;
}

std::string unsafe_path_reason(const std::string& path) {
    if (path.empty()) return "is empty";
    if (path.size() > 1024) return "is longer than 1024 bytes";
    if (const std::string why = text_reason(path); !why.empty()) return why;
    if (path[0] == '/') return "is an absolute path";
    if (path.size() > 1 && path[1] == ':') return "is an absolute path";
    if (path.find(':') != std::string::npos) return "names a scheme or drive (':')";
    for (unsigned char c : path) {
        if (c < 0x20 || c == 0x7f) return "contains a control character";
        if (c == '\\') return "contains a backslash";
        if (c == '$' || c == '`') return "contains a shell character ('$' or '`')";
    }
    size_t start = 0;
    while (start <= path.size()) {
        const size_t slash = std::min(path.find('/', start), path.size());
        const std::string part = path.substr(start, slash - start);
        if (part == "..") return "leaves the upload ('..')";
        if (part.empty() || part == ".") return "has an empty or '.' path segment";
        if (part.size() > 255) return "has a segment longer than 255 bytes (a file system's limit)";
        start = slash + 1;
    }
    return "";
}

namespace {

bool ends_with(const std::string& s, const std::string& suffix) {
    if (s.size() < suffix.size()) return false;
    return std::equal(suffix.rbegin(), suffix.rend(), s.rbegin(),
                      [](char a, char b) { return std::tolower(static_cast<unsigned char>(a)) == b; });
}

// Every external URI of a .gltf must name a file of the same upload. The
// loader checks this too; the server refuses before a file ever reaches it.
void check_gltf_uris(const std::string& gltf_name, const std::string& text, const std::set<std::string>& names) {
    const json doc = json::parse(text, nullptr, false);
    if (doc.is_discarded() || !doc.is_object())
        throw HttpError(400, gltf_name + " is not JSON", {{"field", gltf_name}});
    const fs::path base = fs::path(gltf_name).parent_path();
    for (const char* array : {"buffers", "images"}) {
        if (!doc.contains(array) || !doc[array].is_array()) continue;
        for (size_t i = 0; i < doc[array].size(); ++i) {
            const json& item = doc[array][i];
            if (!item.is_object() || !item.contains("uri")) continue;
            const std::string field = std::string(array) + "[" + std::to_string(i) + "].uri";
            if (!item["uri"].is_string()) throw HttpError(400, field + ": must be a string", {{"field", field}});
            const std::string uri = item["uri"];
            if (uri.rfind("data:", 0) == 0) continue;
            const std::optional<std::string> decoded = protocol::percent_decode(uri);
            if (!decoded)
                throw HttpError(400, field + ": '" + shown_name(uri) + "' has a malformed %-escape",
                                {{"field", field}});
            const std::string& path = *decoded;
            const std::string why = unsafe_path_reason(path);
            if (!why.empty()) throw HttpError(400, field + ": '" + shown_name(uri) + "' " + why, {{"field", field}});
            const std::string full = (base / path).lexically_normal().string();
            if (!names.count(full))
                throw HttpError(400, field + ": '" + shown_name(uri) + "' is not part of the upload",
                                {{"field", field}});
        }
    }
}

// An uploaded file into the upload's temporary directory. A file the disk
// cannot take (full, an I/O error) is the server's trouble: 503, nothing
// stored, never a scene kept cut short (the bytes that did not fit in the
// stream's buffer reach the disk at close, which is checked).
[[noreturn]] void cannot_store(const fs::path& path, const std::string& why) {
    log_line("upload: cannot write " + path.string() + " (" + why + ")");
    throw HttpError(503, "the server cannot store the upload now (" + why + "); nothing was stored, retry later",
                    {{"retry_after", 5}});
}

// Syncs a file, or a directory whose entries changed, to the disk: the
// store that records a scene syncs every commit, so its files must be on
// the disk before it, or a power loss leaves a scene on record without them.
void sync_to_disk(const fs::path& path) {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) cannot_store(path, std::strerror(errno));
    const int synced = ::fsync(fd);
    const int error = errno;
    ::close(fd);
    if (synced != 0) cannot_store(path, std::strerror(error));
}

void write_file(const fs::path& path, const std::string& bytes) {
    std::error_code ec;
    fs::create_directories(path.parent_path(), ec);
    std::ofstream out(path, std::ios::binary);
    out.write(bytes.data(), std::streamsize(bytes.size()));
    out.close();
    if (ec || !out) cannot_store(path, ec ? ec.message() : std::strerror(errno));
    sync_to_disk(path);
}

// The loader's own message without its "lightfarm inspect: error: " prefix.
std::string loader_message(const std::string& line) {
    const std::string marker = "error: ";
    const size_t at = line.find(marker);
    return at == std::string::npos ? line : line.substr(at + marker.size());
}

// Largest texture side in an inspect summary, if it says.
int64_t largest_texture(const json& summary) {
    int64_t largest = 0;
    if (summary.contains("max_texture_size") && summary["max_texture_size"].is_number())
        largest = summary["max_texture_size"].get<int64_t>();
    if (summary.contains("textures") && summary["textures"].is_array()) {
        for (const json& t : summary["textures"]) {
            if (!t.is_object()) continue;
            for (const char* side : {"width", "height"})
                if (t.contains(side) && t[side].is_number()) largest = std::max(largest, t[side].get<int64_t>());
        }
    }
    return largest;
}

// The upload's one .gltf or .glb file, after checking every file's name
// (and a .gltf's URIs against the names). Throws HttpError 400.
const UploadFile& checked_main_file(const std::vector<UploadFile>& files) {
    if (files.empty()) throw HttpError(400, "the upload holds no file");
    std::set<std::string> names;
    std::vector<const UploadFile*> mains;
    for (const UploadFile& f : files) {
        const std::string why = unsafe_path_reason(f.name);
        if (!why.empty())
            throw HttpError(400, "file name '" + shown_name(f.name) + "' " + why, {{"field", shown_name(f.name)}});
        const std::string name = fs::path(f.name).lexically_normal().string();
        if (!names.insert(name).second)
            throw HttpError(400, "file '" + shown_name(f.name) + "' appears twice", {{"field", shown_name(f.name)}});
        if (ends_with(name, ".gltf") || ends_with(name, ".glb")) mains.push_back(&f);
    }
    // A name that is also another's folder ("a" and "a/b") cannot be both.
    for (const std::string& name : names)
        if (const auto inside = names.lower_bound(name + "/");
            inside != names.end() && inside->rfind(name + "/", 0) == 0)
            throw HttpError(400, "file '" + name + "' is also the folder of '" + *inside + "' in the upload",
                            {{"field", name}});
    if (mains.size() != 1)
        throw HttpError(
            400, "an upload holds exactly one .gltf or .glb file, this one holds " + std::to_string(mains.size()));
    const UploadFile& main = *mains.front();
    if (ends_with(main.name, ".glb") && main.bytes.compare(0, 4, "glTF") != 0)
        throw HttpError(400, main.name + " is not a binary glTF (no 'glTF' magic)", {{"field", main.name}});
    if (ends_with(main.name, ".gltf")) check_gltf_uris(main.name, main.bytes, names);
    return main;
}

// The id is the content hash: of the file itself for one file (so it equals
// `sha256sum scene.glb`), else of every (name, size, bytes) in name order.
std::string scene_id(const std::vector<UploadFile>& files) {
    if (files.size() == 1) return sha256_hex(files.front().bytes);
    std::vector<const UploadFile*> sorted;
    for (const UploadFile& f : files) sorted.push_back(&f);
    std::sort(sorted.begin(), sorted.end(), [](auto* a, auto* b) { return a->name < b->name; });
    Sha256 h;
    for (const UploadFile* f : sorted) {
        h.update(f->name);
        h.update(std::string(1, '\0') + std::to_string(f->bytes.size()) + std::string(1, '\0'));
        h.update(f->bytes);
    }
    return h.hex();
}

}  // namespace

SceneStore::SceneStore(const ServerConfig& config, JobStore& store)
    : config_(config), store_(store), engine_(find_engine(config.engine)) {}

class SceneStore::InspectTurn {
public:
    explicit InspectTurn(SceneStore& s) : s_(s) {
        std::unique_lock lock(s_.inspect_mutex_);
        const int slots = std::max(1, s_.config_.max_inspects);
        auto busy = [&] {
            return HttpError(503, "the server is checking too many scene uploads; try again in a few seconds",
                             {{"retry_after", 5}});
        };
        if (s_.inspecting_ >= slots) {
            if (s_.waiting_ >= 4 * slots) throw busy();
            ++s_.waiting_;
            const bool got = s_.inspect_cv_.wait_for(lock, std::chrono::duration<double>(s_.config_.inspect_seconds),
                                                     [&] { return s_.inspecting_ < slots; });
            --s_.waiting_;
            if (!got) throw busy();
        }
        ++s_.inspecting_;
    }
    ~InspectTurn() {
        {
            std::lock_guard lock(s_.inspect_mutex_);
            --s_.inspecting_;
        }
        s_.inspect_cv_.notify_one();
    }
    InspectTurn(const InspectTurn&) = delete;
    InspectTurn& operator=(const InspectTurn&) = delete;

private:
    SceneStore& s_;
};

json SceneStore::inspect(const fs::path& main_file) {
    RunResult r;
    {
        const InspectTurn turn(*this);
        SpawnLimits limits;
        limits.address_space_bytes = config_.inspect_memory_bytes;
        r = run_command({engine_, "inspect", main_file.string(), "--json"},
                        std::chrono::milliseconds(int64_t(config_.inspect_seconds * 1000)), 16 << 20, limits);
    }
    if (r.timed_out)
        throw HttpError(
            400, "scene rejected: the loader took longer than " + std::to_string(int(config_.inspect_seconds)) + " s");
    if (!r.status.exited)
        throw HttpError(400, "scene rejected: the loader crashed on it (" + r.status.describe() + ")");
    if (r.status.code != 0) {
        const std::string why = r.err_last_line.empty() ? r.status.describe() : loader_message(r.err_last_line);
        throw HttpError(400, "scene rejected: " + why);
    }
    json summary = json::parse(r.out, nullptr, false);
    if (!summary.is_object()) {
        log_line("`" + engine_ + " inspect --json` printed no JSON object for an upload");
        throw HttpError(500, "the scene loader gave no summary");
    }

    const int64_t triangles =
        summary.contains("triangles") && summary["triangles"].is_number() ? summary["triangles"].get<int64_t>() : 0;
    if (triangles > config_.limits.triangles)
        throw HttpError(413,
                        "triangles: " + std::to_string(triangles) + " exceeds the limit " +
                            std::to_string(config_.limits.triangles),
                        {{"field", "triangles"}, {"limit", config_.limits.triangles}});
    if (const int64_t side = largest_texture(summary); side > config_.limits.texture_size)
        throw HttpError(413,
                        "textures: a texture of " + std::to_string(side) + " pixels exceeds the limit " +
                            std::to_string(config_.limits.texture_size),
                        {{"field", "textures"}, {"limit", config_.limits.texture_size}});

    return summary;
}

namespace {

// Every file of an upload is in the stored scene's `dir`, whole (its size),
// the main one under the name the scene was first stored as (`stored_main`:
// each tenant names it its own way, SceneRecord::name).
bool files_on_disk(const std::vector<UploadFile>& files, const UploadFile& main, const std::string& stored_main,
                   const fs::path& dir) {
    return std::all_of(files.begin(), files.end(), [&](const UploadFile& f) {
        std::error_code ec;
        const fs::path path = dir / (&f == &main ? fs::path(stored_main) : fs::path(f.name).lexically_normal());
        return fs::is_regular_file(path, ec) && fs::file_size(path, ec) == f.bytes.size() && !ec;
    });
}

}  // namespace

SceneStore::Result SceneStore::upload(const std::vector<UploadFile>& files, const std::string& owner) {
    const UploadFile& main = checked_main_file(files);
    const std::string id = scene_id(files);
    const std::string main_name = fs::path(main.name).lexically_normal().string();
    std::optional<SceneRecord> known = store_.scene(id);
    // Bytes another tenant uploaded before are checked again for this one, so
    // that the answer takes as long as a first upload's: a cached answer in
    // 1 ms told the second tenant the bytes were known (issue #33). The owner
    // itself gets its own scene back at once, under the name it gave first.
    // Files gone from the disk (a dropped mount, a node with a data
    // directory of its own) are written again from this upload: the record
    // stays, and the jobs queued on it find their scene (issue #55).
    const bool on_disk = known && files_on_disk(files, main, known->main_file, DataDir(config_.data_dir).scene(id));
    if (known && on_disk)
        if (std::optional<SceneRecord> own = store_.scene_for(id, owner)) return {*own, false};

    // Write into a private temporary directory, validate there, then move it
    // into place in one rename: a scene directory is never half written.
    const DataDir data(config_.data_dir);
    const fs::path tmp = data.tmp("upload-" + random_hex(8));
    struct Cleanup {
        fs::path dir;
        ~Cleanup() {
            std::error_code ec;
            fs::remove_all(dir, ec);
        }
    } cleanup{tmp};
    for (const UploadFile& f : files) write_file(tmp / fs::path(f.name).lexically_normal(), f.bytes);
    // The files' names too: each directory of the upload holds its entries.
    for (const auto& entry : fs::recursive_directory_iterator(tmp))
        if (entry.is_directory()) sync_to_disk(entry.path());
    sync_to_disk(tmp);

    const json summary = inspect(tmp / main_name);
    // Each owner sees the scene under its own name (its summary's, its jobs',
    // its workers' files): never the name another tenant gave the same bytes.
    auto as_owner_sees_it = [&](const SceneRecord& stored, bool created) {
        SceneRecord own = stored;
        own.name = main_name;
        return Result{store_.scene_for(id, owner).value_or(own), created};
    };
    if (known && on_disk) return as_owner_sees_it(*known, store_.add_scene_owner(id, owner, main_name));

    const fs::path final_dir = data.scene(id);
    std::error_code ec;
    fs::create_directories(final_dir.parent_path(), ec);
    // A scene whose files went missing gets them back as first stored: what
    // is left of it goes first (a rename onto a directory that is not empty
    // fails), and its main file takes the name on record.
    if (known) {
        fs::remove_all(final_dir, ec);
        const fs::path stored_main = tmp / fs::path(known->main_file);
        if (!ec && stored_main != tmp / main_name) {
            fs::create_directories(stored_main.parent_path(), ec);
            if (!ec) fs::rename(tmp / main_name, stored_main, ec);
        }
    }
    if (!ec) fs::rename(tmp, final_dir, ec);
    const bool moved = !ec;
    // A rename fails harmlessly when a concurrent upload of the same bytes
    // won (the directory is there); any other failure (a full disk, an I/O
    // error) stores nothing: a scene on record without its files would fail
    // every job that names it.
    if (!moved && !fs::is_directory(final_dir)) cannot_store(final_dir, ec.message());
    if (moved) {
        try {
            sync_to_disk(final_dir.parent_path());
        } catch (const HttpError&) {
            fs::remove_all(final_dir, ec);  // no directory the store does not know of
            throw;
        }
    }
    if (known) return as_owner_sees_it(*known, store_.add_scene_owner(id, owner, main_name));  // restored
    SceneRecord record{id, main_name, summary};
    try {
        store_.add_scene(record);
    } catch (const StoreError&) {
        // Not recorded: keep no directory the store does not know of.
        if (moved) fs::remove_all(final_dir, ec);
        throw;
    }
    return as_owner_sees_it(record, store_.add_scene_owner(id, owner, main_name));
}

}  // namespace lf::server
