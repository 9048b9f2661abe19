// When a queued job starts (issue #54: "queued, 1 ahead, starts in about
// ..."). The farm's worker slots each come free when the job on it ends: at
// that job's ETA, or, for a job with none yet (still preparing), a typical
// job's time from now; a slot with no job is free now. The jobs ahead of it
// are taken in queue order by the first slot free, each priced at a typical
// job's wall time: the median of the jobs that finished last on this farm
// (a queued job's own bake is not known until it runs). The queued job
// starts when the first slot is free after them.
#pragma once

#include <optional>
#include <vector>

namespace lf::server {

// `slots`: the farm's workers (at least the jobs running); `running_left`:
// each running job's time left, empty where it has no ETA yet;
// `typical_seconds`: a typical job's wall time, empty when no job finished.
// Empty when a job must be priced and nothing prices it.
std::optional<double> queued_start_estimate(int ahead, int slots,
                                            const std::vector<std::optional<double>>& running_left,
                                            std::optional<double> typical_seconds);

// A typical job's wall time: the median of `seconds` (the last jobs'),
// empty when there are none.
std::optional<double> typical_job_seconds(std::vector<double> seconds);

}  // namespace lf::server
