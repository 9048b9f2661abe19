#include "io/image_files.h"

#include "io/write_error.h"
#include "worker_protocol.h"

#include <ImfChannelList.h>
#include <ImfDoubleAttribute.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <ImfStdIO.h>
#include <ImfStringAttribute.h>
#include <ImfThreading.h>

#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <thread>

namespace lf {

namespace fs = std::filesystem;

namespace {

fs::path temp_path_for(const fs::path& path) {
    return path.parent_path() / protocol::temporary_file_name(path.filename().string(), long(getpid()));
}

}  // namespace

const std::vector<float>& FloatImage::at(const std::string& name) const {
    auto it = channels.find(name);
    if (it == channels.end()) throw std::runtime_error("image has no channel '" + name + "'");
    return it->second;
}

void write_file_atomic(const fs::path& path, const std::function<void(std::ostream&)>& write) {
    const fs::path tmp = temp_path_for(path);
    {
        std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
        if (!out) throw write_error(tmp);
        write(out);
        // close(), not flush(): the last bytes reach the file (and a full disk shows) here.
        out.close();
        if (!out) {
            const WriteError error = write_error(tmp);
            std::error_code ignored;
            fs::remove(tmp, ignored);
            throw error;
        }
    }
    commit_file(tmp, path);
}

void write_file_atomic(const fs::path& path, const std::string& bytes) {
    write_file_atomic(path, [&](std::ostream& out) { out.write(bytes.data(), std::streamsize(bytes.size())); });
}

void write_exr(const fs::path& path, const FloatImage& image) {
    // OpenEXR compresses its blocks of lines on its own thread pool: one
    // thread per core (the bytes written are the same).
    static const bool pool = [] {
        Imf::setGlobalThreadCount(int(std::max(1u, std::thread::hardware_concurrency())));
        return true;
    }();
    (void)pool;
    for (const auto& [name, data] : image.channels)
        if (data.size() != size_t(image.width) * size_t(image.height))
            throw std::runtime_error(path.string() + ": channel " + name + " has the wrong size");
    const fs::path tmp = temp_path_for(path);
    // Our own stream, not a file OpenEXR opens: OpenEXR writes the line
    // offsets (and its stream writes the last buffer) in destructors that
    // swallow any error, so a small image on a full disk came out cut short
    // and was renamed into place. The stream keeps the error; close()
    // reports it.
    std::ofstream stream(tmp, std::ios::binary | std::ios::trunc);
    if (!stream) throw write_error(tmp);
    try {
        Imf::Header header(image.width, image.height);
        header.compression() = Imf::ZIP_COMPRESSION;
        for (const auto& [name, value] : image.string_attributes) header.insert(name, Imf::StringAttribute(value));
        for (const auto& [name, value] : image.number_attributes) header.insert(name, Imf::DoubleAttribute(value));
        Imf::FrameBuffer frame;
        for (const auto& [name, data] : image.channels) {
            header.channels().insert(name, Imf::Channel(Imf::FLOAT));
            frame.insert(
                name, Imf::Slice(Imf::FLOAT, (char*)data.data(), sizeof(float), sizeof(float) * size_t(image.width)));
        }
        Imf::StdOFStream exr_stream(stream, tmp.c_str());
        Imf::OutputFile file(exr_stream, header);
        file.setFrameBuffer(frame);
        file.writePixels(image.height);
    } catch (const std::exception& e) {  // OpenEXR's, naming the file and the error (errno's words)
        std::error_code ignored;
        fs::remove(tmp, ignored);
        throw WriteError(path.string() + ": writing EXR failed: " + e.what());
    }
    stream.close();
    if (!stream) {
        const WriteError error = write_error(tmp);
        std::error_code ignored;
        fs::remove(tmp, ignored);
        throw error;
    }
    commit_file(tmp, path);
}

FloatImage read_exr(const fs::path& path) {
    try {
        Imf::InputFile file(path.c_str());
        const Imath::Box2i window = file.header().dataWindow();
        FloatImage image;
        image.width = window.max.x - window.min.x + 1;
        image.height = window.max.y - window.min.y + 1;
        Imf::FrameBuffer frame;
        for (auto it = file.header().channels().begin(); it != file.header().channels().end(); ++it) {
            std::vector<float>& data = image.channel(it.name());
            char* base = (char*)(data.data() - window.min.x - window.min.y * image.width);
            frame.insert(it.name(), Imf::Slice(Imf::FLOAT, base, sizeof(float), sizeof(float) * size_t(image.width)));
        }
        file.setFrameBuffer(frame);
        file.readPixels(window.min.y, window.max.y);
        for (auto it = file.header().begin(); it != file.header().end(); ++it) {
            if (auto* s = dynamic_cast<const Imf::StringAttribute*>(&it.attribute()))
                image.string_attributes[it.name()] = s->value();
            else if (auto* d = dynamic_cast<const Imf::DoubleAttribute*>(&it.attribute()))
                image.number_attributes[it.name()] = d->value();
        }
        return image;
    } catch (const std::exception& e) {
        throw std::runtime_error(path.string() + ": reading EXR failed: " + e.what());
    }
}

FloatImage read_pfm(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error(path.string() + ": cannot open");
    std::string kind;
    int width = 0, height = 0;
    double scale = 0.0;
    in >> kind >> width >> height >> scale;
    in.get();  // the single whitespace after the header
    if ((kind != "PF" && kind != "Pf") || width <= 0 || height <= 0 || width > 65536 || height > 65536)
        throw std::runtime_error(path.string() + ": not a PFM file");
    const int components = kind == "PF" ? 3 : 1;
    std::vector<float> raw(size_t(width) * size_t(height) * size_t(components));
    in.read(reinterpret_cast<char*>(raw.data()), std::streamsize(raw.size() * sizeof(float)));
    if (!in) throw std::runtime_error(path.string() + ": truncated PFM data");
    if (scale > 0.0) {  // big-endian
        for (float& f : raw) {
            uint32_t u;
            std::memcpy(&u, &f, 4);
            u = __builtin_bswap32(u);
            std::memcpy(&f, &u, 4);
        }
    }
    FloatImage image;
    image.width = width;
    image.height = height;
    const char* names[3] = {"R", "G", "B"};
    for (int c = 0; c < components; ++c) {
        std::vector<float>& data = image.channel(components == 1 ? "Y" : names[c]);
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x)  // PFM rows go bottom to top
                data[size_t(y) * size_t(width) + size_t(x)] =
                    raw[(size_t(height - 1 - y) * size_t(width) + size_t(x)) * size_t(components) + size_t(c)];
    }
    return image;
}

}  // namespace lf
