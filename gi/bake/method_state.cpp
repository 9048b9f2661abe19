#include "bake/method_state.h"

#include "io/image_files.h"
#include "io/write_error.h"

#include <cstring>
#include <fstream>

namespace lf {

namespace fs = std::filesystem;

namespace {

constexpr char kMagic[8] = {'L', 'F', 'S', 'T', 'A', 'T', 'E', '1'};

// The checksum of a file's parts, in the order they are written.
class Checksum {
public:
    void add(const void* data, size_t bytes) { value_ = hash_bytes(data, bytes, value_); }
    uint64_t value() const { return value_; }

private:
    uint64_t value_ = 0xcbf29ce484222325ull;
};

void put_u64(std::ostream& out, Checksum& sum, uint64_t v) {
    unsigned char b[8];
    for (int i = 0; i < 8; ++i) b[i] = static_cast<unsigned char>(v >> (8 * i));
    out.write(reinterpret_cast<const char*>(b), 8);
    sum.add(b, 8);
}

uint64_t u64_of(const unsigned char* b) {
    uint64_t v = 0;
    for (int i = 0; i < 8; ++i) v |= uint64_t(b[i]) << (8 * i);
    return v;
}

nlohmann::json header_of(const MethodState& s) {
    nlohmann::json sizes = nlohmann::json::array();
    for (const auto& b : s.buffers) sizes.push_back(b.size());
    return {{"key", s.key},           {"layout", s.layout}, {"stats", protocol::to_json(s.stats)},
            {"counters", s.counters}, {"files", s.files},   {"buffers", sizes}};
}

}  // namespace

void write_method_state(const fs::path& path, const MethodState& state) {
    make_directories(path.parent_path());
    write_file_atomic(path, [&](std::ostream& out) {
        Checksum sum;
        out.write(kMagic, sizeof kMagic);
        sum.add(kMagic, sizeof kMagic);
        const std::string header = header_of(state).dump();
        put_u64(out, sum, header.size());
        out.write(header.data(), std::streamsize(header.size()));
        sum.add(header.data(), header.size());
        for (const auto& b : state.buffers) {
            out.write(reinterpret_cast<const char*>(b.data()), std::streamsize(b.size()));
            sum.add(b.data(), b.size());
        }
        put_u64(out, sum, sum.value());
    });
}

MethodState read_method_state(const fs::path& path) {
    const auto fail = [&](const std::string& why) {
        return MethodStateMismatch(path.filename().string() + ": " + why);
    };
    std::ifstream in(path, std::ios::binary);
    if (!in) throw fail("cannot be read");
    Checksum sum;
    const auto read = [&](void* to, size_t bytes, const char* what) {
        in.read(static_cast<char*>(to), std::streamsize(bytes));
        if (size_t(in.gcount()) != bytes) throw fail(std::string("truncated in its ") + what);
        sum.add(to, bytes);
    };
    char magic[8];
    read(magic, sizeof magic, "signature");
    if (std::memcmp(magic, kMagic, sizeof kMagic) != 0) throw fail("not a lightfarm method state");
    unsigned char word[8];
    read(word, 8, "header");
    const uint64_t header_size = u64_of(word);
    if (header_size > (uint64_t(1) << 30)) throw fail("header size out of range");
    std::string text(header_size, '\0');
    read(text.data(), text.size(), "header");

    MethodState state;
    try {
        const nlohmann::json header = nlohmann::json::parse(text);
        state.key = header.at("key").get<std::string>();
        state.layout = header.at("layout").get<uint64_t>();
        state.stats = protocol::progress_from_json(header.at("stats"));
        state.counters = header.at("counters").get<std::vector<int64_t>>();
        state.files = header.at("files").get<std::vector<std::string>>();
        // Sizes are checked against the file before anything is allocated.
        uint64_t total = sizeof kMagic + 8 + header_size + 8;
        std::error_code ec;
        const uint64_t file_size = fs::file_size(path, ec);
        std::vector<uint64_t> sizes;
        for (const auto& size : header.at("buffers")) {
            sizes.push_back(size.get<uint64_t>());
            total += sizes.back();
            if (ec || total > file_size) throw fail("shorter than its header says");
        }
        if (total != file_size) throw fail("longer than its header says");
        for (const uint64_t size : sizes) state.buffers.emplace_back(size_t(size));
    } catch (const nlohmann::json::exception& e) {
        throw fail(std::string("bad header: ") + e.what());
    }
    for (auto& b : state.buffers) read(b.data(), b.size(), "buffers");
    const uint64_t expected = sum.value();
    in.read(reinterpret_cast<char*>(word), 8);
    if (in.gcount() != 8) throw fail("truncated before its checksum");
    if (u64_of(word) != expected) throw fail("checksum does not match (the file is damaged)");
    return state;
}

std::vector<std::byte> buffer_bytes(const GpuBuffer& buffer) { return buffer.read<std::byte>(); }

void restore_buffers(const std::vector<std::pair<GpuBuffer*, std::string>>& to,
                     const std::vector<std::vector<std::byte>>& from) {
    if (to.size() != from.size())
        throw MethodStateMismatch("the state has " + std::to_string(from.size()) + " buffers, this bake " +
                                  std::to_string(to.size()));
    for (size_t i = 0; i < to.size(); ++i)
        if (from[i].size() != to[i].first->bytes())
            throw MethodStateMismatch(to[i].second + ": the state holds " + std::to_string(from[i].size()) +
                                      " bytes, this bake " + std::to_string(to[i].first->bytes()));
    for (size_t i = 0; i < to.size(); ++i) to[i].first->upload(from[i].data(), from[i].size());
}

}  // namespace lf
