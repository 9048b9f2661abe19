// A family of drawn configurations judged as issue #52 asks: each reading's
// error |estimate - truth| / max(truth, 10% of the family's brightest truth)
// (a dark point is judged against the family's light, not against its own
// zero), then the 95th percentile and the worst.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <random>
#include <vector>

namespace lf::test {

// A family's draws: from a fixed seed, printed so a failure can be replayed.
inline std::mt19937 family_rng(unsigned seed) {
    std::printf("  seed %u\n", seed);
    return std::mt19937(seed);
}

struct Reading {
    double estimate, truth;
};

struct FamilyErrors {
    double p95 = 0.0, worst = 0.0;
};

inline FamilyErrors family_errors(const std::vector<Reading>& readings) {
    double brightest = 0.0;
    for (const Reading& r : readings) brightest = std::max(brightest, r.truth);
    std::vector<double> errors;
    for (const Reading& r : readings)
        errors.push_back(std::abs(r.estimate - r.truth) / std::max(r.truth, 0.1 * brightest));
    if (errors.empty()) return {};
    std::sort(errors.begin(), errors.end());
    return {errors[size_t(0.95 * double(errors.size() - 1))], errors.back()};
}

}  // namespace lf::test
