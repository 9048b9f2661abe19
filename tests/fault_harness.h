// The fault harness (issue #33): the LD_PRELOAD shim's settings
// (fault_shim.cpp), the dry run's sites, and the tables of what each fault
// did, which docs/service.md must hold. Used by test_server_faults.cpp and
// test_worker_faults.cpp.
//
// The faults come from a shim rather than a seam in our write functions:
// the store's calls are SQLite's, the EXR writes OpenEXR's, and a seam sees
// only the calls someone remembered to route through it. The shim sees them
// all: writes (write, writev, pwrite, pwritev, fsync, fdatasync), creating
// opens, mkdir, rename, link, ftruncate, copies and closes; it names each
// by its "site": the process, the operation and the file's path in the data
// or output directory, ids and numbers as '#'.
//
// Each test first runs its scenario once without a fault (the dry run),
// which lists the sites and how many calls each makes, then runs it again
// for each site, each of its calls (calls_to_fail) and each error, failing
// that call. The tables of sites and results in docs/service.md must be the
// ones the tests find: a site added or a result changed fails the test,
// which prints the new table.
#pragma once

#include "server_harness.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <functional>
#include <map>
#include <regex>
#include <set>
#include <string>
#include <vector>

namespace lf::test {

inline const std::vector<std::string> kErrors = {"ENOSPC", "EIO"};

inline fs::path example_scene(const std::string& name) {
    const char* env = std::getenv("LIGHTFARM_SCENES");
    return fs::path(env ? env : LIGHTFARM_EXAMPLES) / name;
}

// The shim's settings, as environment variables of the processes this test
// starts while a FaultShim lives (posix_spawn and popen pass environ on), or
// only of the processes given environment() (Export::kExplicitly): shims of
// that kind can live side by side, each with the processes of its own run.
class FaultShim {
public:
    enum class Export { kThisProcess, kExplicitly };
    // `site` empty: a dry run, which logs every call's site. Otherwise the
    // `nth` call of `site` after each arm() fails with `error`.
    FaultShim(const fs::path& root, const fs::path& dir, const std::string& site = "", const std::string& error = "",
              int nth = 1, Export to = Export::kThisProcess)
        : log_(dir / "writes.log"), armed_(dir / "armed"), export_(to) {
        fs::create_directories(dir);
        set("LD_PRELOAD", LIGHTFARM_FAULT_SHIM);
        set("LF_FAULT_ROOT", fs::weakly_canonical(root).string());
        set("LF_FAULT_ARMED", armed_.string());
        if (site.empty()) set("LF_FAULT_LOG", log_.string());
        else {
            set("LF_FAULT_SITE", site);
            set("LF_FAULT_ERRNO", error);
            set("LF_FAULT_NTH", std::to_string(nth));
        }
    }
    ~FaultShim() {
        if (export_ == Export::kThisProcess)
            for (const auto& [name, value] : environment_) unsetenv(name.c_str());
    }
    // Only the calls of these processes count (by name; the shim's default
    // is "lightfarmd lightfarm"), which may run as another user: the log
    // and the armed file are made theirs to write too.
    void count_only(const std::string& processes) {
        set("LF_FAULT_PROCS", processes);
        write_text(armed_, "-");  // not armed yet
        for (const fs::path& file : {log_, armed_}) {
            std::ofstream(file, std::ios::app).flush();
            fs::permissions(file, fs::perms::owner_read | fs::perms::owner_write | fs::perms::group_read |
                                      fs::perms::group_write | fs::perms::others_read | fs::perms::others_write);
        }
        fs::permissions(log_.parent_path(), fs::perms::all);
    }
    // The settings as "NAME=VALUE", for a process started by other means (env(1), spawn_lightfarmd).
    std::vector<std::string> environment() const {
        std::vector<std::string> all;
        for (const auto& [name, value] : environment_) all.push_back(name + "=" + value);
        return all;
    }
    // From now on the site's nth call fails, once: the shim appends an 'x'.
    void arm() const { write_text(armed_, ""); }
    bool fired() const { return read_text(armed_).find('x') != std::string::npos; }
    // No fault from now on, if none was taken.
    void disarm() const {
        if (read_text(armed_).empty()) write_text(armed_, "-");
    }
    // A line of the harness's own in the log: where a phase of the scenario begins.
    void mark(const std::string& phase) const { std::ofstream(log_, std::ios::app) << "@" << phase << "\n"; }
    // The dry run's sites in the order first called, each as "PHASE SITE".
    std::vector<std::string> sites() const {
        std::vector<std::string> sites;
        for (const auto& [site, calls] : calls_in_order())
            if (std::find(sites.begin(), sites.end(), site) == sites.end()) sites.push_back(site);
        return sites;
    }
    // How many calls the dry run made at each "PHASE SITE".
    std::map<std::string, int> calls() const {
        std::map<std::string, int> calls;
        for (const auto& [site, n] : calls_in_order()) calls[site] = n;
        return calls;
    }

    // Each call of the log, in order, as ("PHASE SITE", how many such calls so far).
    std::vector<std::pair<std::string, int>> calls_in_order() const {
        std::vector<std::pair<std::string, int>> calls;
        std::map<std::string, int> so_far;
        std::string phase = "start", line;
        std::ifstream in(log_);
        while (std::getline(in, line)) {
            if (line.rfind('@', 0) == 0) phase = line.substr(1);
            else {
                const std::string site = phase + " " + line;
                calls.emplace_back(site, ++so_far[site]);
            }
        }
        return calls;
    }

private:
    void set(const std::string& name, const std::string& value) {
        if (export_ == Export::kThisProcess) setenv(name.c_str(), value.c_str(), 1);
        environment_[name] = value;
    }
    fs::path log_, armed_;
    Export export_;
    std::map<std::string, std::string> environment_;
};

// A file name as the shim writes it in a site: any word with a digit, or of
// 8 hex digits or more, as '#' ("lightmap.pass-0004.exr" -> "lightmap.pass-#.exr").
inline std::string as_in_site(const std::string& name) {
    static const std::regex word("[A-Za-z0-9]+"), numeric(".*[0-9].*|[0-9a-f]{8,}");
    std::string out;
    size_t at = 0;
    for (auto it = std::sregex_iterator(name.begin(), name.end(), word); it != std::sregex_iterator(); ++it) {
        out += name.substr(at, size_t(it->position()) - at);
        out += std::regex_match(it->str(), numeric) ? "#" : it->str();
        at = size_t(it->position() + it->length());
    }
    return out + name.substr(at);
}

// The file a site names, without its directory: "lightfarm write
// .resume/.ao.state.tmp-#" -> ".ao.state.tmp-#".
inline std::string file_of(const std::string& site) {
    return fs::path(site.substr(site.rfind(' ') + 1)).filename().string();
}

// Every file left under `root` was seen written by the shim: a file written
// through a path the shim cannot see (glibc's stdio) would be missing. Files
// are written under a temporary name and renamed, so a file counts as seen
// when a site's last part contains its name ("lightmap.exr" is written as
// ".lightmap.exr.tmp-#"). `skip`: files this check is not about.
inline void expect_every_file_seen(const fs::path& root, const std::vector<std::string>& sites,
                                   const std::function<bool(const std::string&)>& skip) {
    for (const auto& entry : fs::recursive_directory_iterator(root)) {
        if (!entry.is_regular_file() || entry.file_size() == 0) continue;
        const std::string name = as_in_site(entry.path().filename().string());
        if (skip(fs::relative(entry.path(), root).string())) continue;
        bool seen = false;
        for (const std::string& site : sites) seen |= file_of(site).find(name) != std::string::npos;
        EXPECT_TRUE(seen) << entry.path() << " was written by no write the shim saw";
    }
}

// The table between "<!-- NAME table: ... -->" and "<!-- end of the NAME
// table -->" in docs/service.md must be `table`: a site added, gone or
// answered otherwise fails here, printing the table to put there. With
// LIGHTFARM_WRITE_FAULT_TABLES=1 the test writes it there itself.
inline void expect_doc_table(const std::string& name, const std::string& table) {
    const fs::path doc = fs::path(LIGHTFARM_SOURCE_DIR) / "docs" / "service.md";
    std::string text = read_text(doc);
    const std::string begin_mark = "<!-- " + name + " table:", end_mark = "<!-- end of the " + name + " table -->";
    const size_t begin = text.find('\n', text.find(begin_mark)) + 1, end = text.find(end_mark);
    ASSERT_TRUE(text.find(begin_mark) != std::string::npos && end != std::string::npos && begin <= end)
        << doc << " has no " << begin_mark << " ... " << end_mark;
    if (std::getenv("LIGHTFARM_WRITE_FAULT_TABLES")) {
        text.replace(begin, end - begin, table);
        std::ofstream(doc, std::ios::binary) << text;
        return;
    }
    EXPECT_EQ(text.substr(begin, end - begin), table)
        << "docs/service.md's " << name << " table is not what the harness finds; it should read:\n"
        << table;
}

// One markdown row.
inline std::string row(const std::vector<std::string>& cells) {
    std::string line = "|";
    for (const std::string& c : cells) line += " " + c + " |";
    return line + "\n";
}

// How many calls the dry run made at each site in each phase: "lightfarmd
// write jobs.sqlite-wal" -> {"start": 3, "upload": 2, …}.
inline std::map<std::string, std::map<std::string, int>> calls_by_site(const std::map<std::string, int>& calls) {
    std::map<std::string, std::map<std::string, int>> by_site;
    for (const auto& [s, n] : calls) {
        const size_t space = s.find(' ');
        by_site[s.substr(space + 1)][s.substr(0, space)] = n;
    }
    return by_site;
}

// The calls of a site's n in a phase that the harness fails: every one up
// to three; beyond (SQLite's pages: up to 53 writes of its WAL at a start),
// the first, the middle and the last. Calls of one SQLite transaction are
// answered alike (the table's rows show where they differ); failing all 53
// of each would take more of the CI's time than the whole harness.
inline std::set<int> calls_to_fail(int n) {
    if (n <= 3) {
        std::set<int> all;
        for (int i = 1; i <= n; ++i) all.insert(i);
        return all;
    }
    return {1, (n + 1) / 2, n};
}

// A call of n in the tables: its number, or where n is over three (a count
// that varies with the store's timing) "first", "middle" or "last".
inline std::string call_name(int call, int n) {
    if (n <= 3) return std::to_string(call);
    return call == 1 ? "first" : call == n ? "last" : "middle";
}
inline std::string calls_cell(int n) { return n <= 3 ? std::to_string(n) : "over 3"; }

// What failing each of a site's n calls did, in a table cell: the effect
// when every call had the same; else each effect with the calls that had it.
inline std::string summary(const std::map<int, std::string>& effect_by_call, int n) {
    std::map<std::string, std::vector<int>> calls_by_effect;
    for (const auto& [call, effect] : effect_by_call) calls_by_effect[effect].push_back(call);
    if (calls_by_effect.size() == 1) return calls_by_effect.begin()->first;
    std::string cell;
    for (const auto& [effect, calls] : calls_by_effect) {
        cell += (cell.empty() ? "" : "; ") + effect + " (";
        for (size_t i = 0; i < calls.size(); ++i) cell += (i ? ", " : "") + call_name(calls[i], n);
        cell += ")";
    }
    return cell;
}

// The site without its process: "write jobs.sqlite-wal".
inline std::string operation_and_path(const std::string& site) { return site.substr(site.find(' ') + 1); }

}  // namespace lf::test
