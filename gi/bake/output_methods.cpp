#include "bake/output_methods.h"

#include "bake/ambient_occlusion_method.h"
#include "bake/probes_method.h"
#include "bake/radiosity_map_method.h"
#include "bake/sh_transfer_method.h"

#include <map>

namespace lf {

namespace {

template <class Method>
std::unique_ptr<ProgressiveMethod> make(const PreparedScene& prepared, const protocol::BakeSettings& settings) {
    return std::make_unique<Method>(prepared, settings);
}

}  // namespace

MethodFactory method_factory(const std::string& name) {
    static const std::map<std::string, MethodFactory> factories = {
        {"lightmap", &make<RadiosityMapMethod>},
        {"sh", &make<ShTransferMethod>},
        {"probes", &make<ProbesMethod>},
        {"ao", &make<AmbientOcclusionMethod>},
    };
    const auto it = factories.find(name);
    return it == factories.end() ? nullptr : it->second;
}

}  // namespace lf
