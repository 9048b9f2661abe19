// Wall time since a point, in seconds (the steady clock): what every timed
// stage, pass batch and benchmark in gi reports.
#pragma once

#include <chrono>

namespace lf {

class Stopwatch {
public:
    double seconds() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count(); }

private:
    std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

}  // namespace lf
