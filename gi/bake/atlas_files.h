// An atlas image's files. The bake sees an atlas of several pages stacked
// (LightmapPages); an engine takes one lightmap per page.
#pragma once

#include "io/image_files.h"
#include "scene/scene.h"

#include <filesystem>
#include <string>
#include <vector>

namespace lf {

// Page `page` of `atlas`: its rows, every channel, the header's attributes
// with lightfarm.page and lightfarm.pages added.
FloatImage atlas_page(const FloatImage& atlas, const LightmapPages& pages, int page);

// Writes `name` ("lightmap.exr": the atlas as baked, its pages stacked) and,
// where there are several pages, each page as its own file
// (protocol::page_file_name: "lightmap.page-0.exr", …). Returns the names
// written.
std::vector<std::string> write_atlas_exr(const std::filesystem::path& dir, const std::string& name,
                                         const FloatImage& atlas, const LightmapPages& pages);

// What the manifest says of the page files, beside its own description of `name`.
std::string page_files_description(const std::string& name);

}  // namespace lf
