// A small command-line reader: positional arguments and --key value /
// --flag options, with an error for anything unknown.
#pragma once

#include <algorithm>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

namespace lf::cli {

class UsageError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

class Args {
public:
    // `valued`: options that take a value; `flags`: options that do not.
    Args(int argc, char** argv, int first, const std::set<std::string>& valued, const std::set<std::string>& flags) {
        for (int i = first; i < argc; ++i) {
            std::string a = argv[i];
            if (a.rfind("--", 0) != 0 || a == "--") {
                positional_.push_back(a);
                continue;
            }
            std::string value;
            const size_t eq = a.find('=');
            std::string key = a.substr(0, eq);
            if (flags.count(key)) {
                if (eq != std::string::npos) throw UsageError(key + " takes no value");
                flags_.insert(key);
            } else if (valued.count(key)) {
                if (eq != std::string::npos) value = a.substr(eq + 1);
                else if (i + 1 < argc) value = argv[++i];
                else throw UsageError(key + " needs a value");
                values_[key] = value;
            } else {
                throw UsageError("unknown option " + key + did_you_mean(key, valued, flags));
            }
        }
    }
    const std::vector<std::string>& positional() const { return positional_; }
    bool flag(const std::string& key) const { return flags_.count(key) > 0; }
    bool has(const std::string& key) const { return values_.count(key) > 0; }
    std::string get(const std::string& key, const std::string& fallback = "") const {
        auto it = values_.find(key);
        return it == values_.end() ? fallback : it->second;
    }
    double number(const std::string& key, double fallback) const {
        return has(key) ? parse_number(key, values_.at(key)) : fallback;
    }
    // A comma-separated list ("1,2,4"), or `fallback` when the option is absent.
    std::vector<double> numbers(const std::string& key, std::vector<double> fallback) const {
        if (!has(key)) return fallback;
        std::vector<double> list;
        const std::string& text = values_.at(key);
        for (size_t start = 0;;) {
            const size_t comma = text.find(',', start);
            list.push_back(parse_number(key, text.substr(start, comma - start)));
            if (comma == std::string::npos) return list;
            start = comma + 1;
        }
    }

private:
    // " (did you mean --passes?)" for the known option nearest a mistyped
    // one, when it is near enough to be what was meant; else "".
    static std::string did_you_mean(const std::string& key, const std::set<std::string>& valued,
                                    const std::set<std::string>& flags) {
        std::string best;
        size_t best_distance = std::string::npos;
        for (const std::set<std::string>* known : {&valued, &flags})
            for (const std::string& option : *known) {
                const size_t d = edit_distance(key, option);
                if (d < best_distance) best_distance = d, best = option;
            }
        const size_t near_enough = std::max<size_t>(1, key.size() / 4);
        return best_distance <= near_enough ? " (did you mean " + best + "?)" : "";
    }
    // Levenshtein distance: insertions, deletions and substitutions.
    static size_t edit_distance(const std::string& a, const std::string& b) {
        std::vector<size_t> row(b.size() + 1);
        for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
        for (size_t i = 1; i <= a.size(); ++i) {
            size_t diagonal = row[0];
            row[0] = i;
            for (size_t j = 1; j <= b.size(); ++j) {
                const size_t above = row[j];
                row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
                diagonal = above;
            }
        }
        return row[b.size()];
    }

    static double parse_number(const std::string& key, const std::string& text) {
        size_t used = 0;
        double v = 0.0;
        try {
            v = std::stod(text, &used);
        } catch (const std::exception&) {
            used = 0;
        }
        if (used != text.size() || text.empty()) throw UsageError(key + ": '" + text + "' is not a number");
        return v;
    }

    std::vector<std::string> positional_;
    std::set<std::string> flags_;
    std::map<std::string, std::string> values_;
};

}  // namespace lf::cli
