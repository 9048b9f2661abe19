#include "bake_help.h"

#include "bake_settings.h"

#include <algorithm>

namespace lf::cli {

std::string bake_settings_help() {
    std::string text = "settings (of `lightfarm bake` and `lightfarm submit`):\n";
    for (const protocol::Setting& s : protocol::setting_catalog()) {
        std::string flag = s.flag() + (s.value_syntax().empty() ? "" : " " + s.value_syntax());
        flag.resize(std::max<size_t>(flag.size(), 34), ' ');
        text += "  " + flag + " " + s.help;
        if (!s.default_value.is_null() && s.type != protocol::SettingType::Flag)
            text += " [" + (s.default_value.is_string() ? s.default_value.get<std::string>() : s.default_value.dump()) +
                    "]";
        text += "\n";
    }
    return text;
}

// The outputs a bake can ask for, from the registry (protocol/outputs.h).
std::string bake_outputs_help() {
    std::string text = "outputs (any number; without one, the first):\n";
    for (const protocol::OutputKind& o : protocol::output_registry()) {
        std::string flag = "--" + o.name;
        flag.resize(std::max<size_t>(flag.size(), 34), ' ');
        text += "  " + flag + " " + o.help + "\n";
    }
    return text;
}

std::string bake_help() {
    std::string outputs;
    for (const std::string& o : protocol::output_names()) outputs += " [--" + o + "]";
    return "usage: lightfarm bake SCENE --out DIR [--spec SPEC.json]" + outputs +
           "\n"
           "                      [--device auto|gpu|gpu:N|cpu] [--json] [--resume] [settings]\n\n"
           "  --resume  continue an interrupted bake into the same DIR from its last snapshot\n"
           "            (an output whose saved state is another bake's starts from pass 0)\n\n" +
           bake_outputs_help() + "\n" + bake_settings_help();
}

}  // namespace lf::cli
