#include "bake_help.h"

#include "bake_settings.h"

#include <algorithm>

namespace lf::cli {

std::string bake_settings_help() {
    std::string text = "settings (of `lightfarm bake` and `lightfarm submit`):\n";
    for (const protocol::Setting& s : protocol::setting_catalog()) {
        std::string flag = s.flag() + (s.value_syntax().empty() ? "" : " " + s.value_syntax());
        flag.resize(std::max<size_t>(flag.size(), 34), ' ');
        // A flag that is on unless turned off is shown by its --no- form:
        // what it turns off, said as such (the help read as if it turned it on).
        const bool off_switch = s.type == protocol::SettingType::Flag && s.default_value == true;
        text += "  " + flag + " " + (off_switch ? "turn off the " + s.help + " (on by default)" : s.help);
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
           "                      [--device auto|gpu|gpu:N|cpu] [--json] [--resume] [settings]\n"
           "       lightfarm bake SCENE --plan [--json] [--OUTPUT …] [settings]\n\n"
           "  --resume  continue an interrupted bake into the same DIR from its last snapshot\n"
           "            (an output whose saved state is another bake's starts from pass 0)\n"
           "  --plan    print the atlas this bake would make (size, texel density, charts,\n"
           "            border fraction) and its warnings, without baking\n\n" +
           bake_outputs_help() + "\n" + bake_settings_help();
}

std::string command_usage(const std::string& usage, const std::string& command) {
    std::string out;
    size_t at = 0;
    bool inside = false;
    while (at < usage.size()) {
        const size_t end = std::min(usage.find('\n', at), usage.size());
        const std::string line = usage.substr(at, end - at);
        at = end + 1;
        const bool entry = line.rfind("  " + command + " ", 0) == 0 || line == "  " + command;
        const bool continuation = line.rfind("       ", 0) == 0;  // deeper than an entry's two spaces
        if (entry) {
            inside = true;
            out += "usage: lightfarm " + line.substr(2) + "\n";
        } else if (inside && continuation) {
            out += line + "\n";
        } else if (inside) {
            break;
        }
    }
    return out;
}

}  // namespace lf::cli
