// URI text, one rule for every reader of a glTF's URIs and an upload's
// names: the engine's loader (gi/scene/gltf_files.cpp), the server's upload
// check (server/scene_store.cpp) and the CLI's upload (client_cli/remote.cpp)
// decode the same bytes to the same name, or all refuse them.
#pragma once

#include <optional>
#include <string>
#include <string_view>

namespace lf::protocol {

// RFC 3986 percent-decoding: "%XX" (hex, either case) is that byte, any
// other character is itself ('+' stays '+': that is form decoding, not a
// URI's). Empty for a malformed escape ('%' without two hex digits after).
std::optional<std::string> percent_decode(std::string_view text);

}  // namespace lf::protocol
