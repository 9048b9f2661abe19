#include "bake_reporter.h"

#include "job_status.h"
#include "remote.h"

#include <unistd.h>

#include <iostream>

namespace lf::cli {

BakeReporter::BakeReporter(bool json, const protocol::BakeSettings& settings)
    : json_(json), terminal_(!json && isatty(STDERR_FILENO)), job_(settings) {}

void BakeReporter::operator()(const protocol::WorkerEvent& e) {
    if (json_) {
        std::cout << protocol::to_json(e).dump() << std::endl;  // one object per line, flushed
        return;
    }
    if (const auto* prepare = std::get_if<protocol::PrepareEvent>(&e); prepare && terminal_) {
        std::cerr << "\r" << preparing_line("", *prepare) << "    " << std::flush;
        preparing_drawn_ = true;
    } else if (const auto* start = std::get_if<protocol::StartEvent>(&e)) {
        if (preparing_drawn_) std::cerr << "\n";
        print_start(*start);
    } else if (const auto* progress = std::get_if<protocol::ProgressEvent>(&e); progress && terminal_) {
        draw_progress(*progress);
    } else if (const auto* done = std::get_if<protocol::DoneEvent>(&e)) {
        if (terminal_) std::cerr << "\n";
        std::cout << "done: " << done->progress.pass << " passes, " << done->progress.rays << " rays, "
                  << done->progress.seconds << " s, error estimate " << done->progress.error_estimate.value_or(0.0)
                  << "\n";
    }
}

// What is baked (each output's size), on what, and what was resumed.
void BakeReporter::print_start(const protocol::StartEvent& start) {
    std::cerr << "baking";
    for (auto it = start.outputs.begin(); it != start.outputs.end(); ++it)
        std::cerr << " " << it.key() << " ("
                  << (it.value().contains("texels") ? std::to_string(it.value()["texels"].get<uint64_t>()) + " texels)"
                      : it.value().contains("probes")
                          ? std::to_string(it.value()["probes"].get<uint64_t>()) + " probes)"
                          : std::to_string(it.value().value("vertices", uint64_t(0))) + " vertices)");
    std::cerr << " on " << start.renderer << ", prepared in " << start.prepare_seconds << " s\n";
    job_.start(start);
    for (const auto& [output, at] : start.resumed) std::cerr << output << ": resumed after pass " << at.pass << "\n";
    for (const auto& [output, why] : start.not_resumed)
        std::cerr << output << ": not resumed, from pass 0: " << why << "\n";
    for (const std::string& warning : start.warnings) std::cerr << "warning: " << warning << "\n";
}

void BakeReporter::draw_progress(const protocol::ProgressEvent& progress) {
    if (progress.output != drawing_ && !drawing_.empty()) std::cerr << "\n";
    drawing_ = progress.output;
    // The same line as `submit --wait` and `watch` draw: the whole job's
    // share done and ETA, each output ending at its first stop rule met.
    const protocol::Progress shown = job_.update(progress.output, progress.progress);
    std::cerr << "\r" << progress_line("", progress.output, shown) << "    " << std::flush;
}

}  // namespace lf::cli
