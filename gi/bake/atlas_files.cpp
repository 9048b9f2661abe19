#include "bake/atlas_files.h"

#include "worker_protocol.h"

#include <algorithm>
#include <stdexcept>

namespace lf {

FloatImage atlas_page(const FloatImage& atlas, const LightmapPages& pages, int page) {
    if (pages.count == 1) return atlas;
    if (page < 0 || page >= pages.count || atlas.height != pages.total_rows())
        throw std::logic_error("atlas_page: page " + std::to_string(page) + " of an atlas of " +
                               std::to_string(atlas.height) + " rows, not " + std::to_string(pages.count) +
                               " pages of " + std::to_string(pages.rows));
    FloatImage out;
    out.width = atlas.width;
    out.height = pages.rows;
    out.string_attributes = atlas.string_attributes;
    out.number_attributes = atlas.number_attributes;
    out.number_attributes["lightfarm.page"] = page;
    out.number_attributes["lightfarm.pages"] = pages.count;
    const size_t first = size_t(page) * size_t(pages.stride()) * size_t(atlas.width);
    const size_t count = size_t(pages.rows) * size_t(atlas.width);
    for (const auto& [channel, values] : atlas.channels)
        out.channels[channel].assign(values.begin() + std::ptrdiff_t(first),
                                     values.begin() + std::ptrdiff_t(first + count));
    return out;
}

std::vector<std::string> write_atlas_exr(const std::filesystem::path& dir, const std::string& name,
                                         const FloatImage& atlas, const LightmapPages& pages) {
    write_exr(dir / name, atlas);
    std::vector<std::string> files{name};
    const std::filesystem::path file(name);
    for (int page = 0; pages.count > 1 && page < pages.count; ++page) {
        files.push_back(protocol::page_file_name(file.stem().string(), page, file.extension().string().substr(1)));
        write_exr(dir / files.back(), atlas_page(atlas, pages, page));
    }
    return files;
}

std::string page_files_description(const std::string& name) {
    return "one atlas page (N from 0) of " + name + ": its rows from N x (page_height + page_gap) (the atlas in " +
           "this output's settings), as scene.lit.glb's materials of page N take it";
}

}  // namespace lf
