// LIGHTFARM_THREADS for a scope (gi/util/parallel.h): tests that compare
// what preparation makes on one thread and on several.
#pragma once

#include <cstdlib>
#include <string>

namespace lf::test {

// Sets LIGHTFARM_THREADS to `n` for its lifetime, then restores it.
class ThreadCount {
public:
    explicit ThreadCount(const char* n) {
        if (const char* old = std::getenv("LIGHTFARM_THREADS")) old_ = old;
        setenv("LIGHTFARM_THREADS", n, 1);
    }
    ~ThreadCount() {
        if (old_.empty()) unsetenv("LIGHTFARM_THREADS");
        else setenv("LIGHTFARM_THREADS", old_.c_str(), 1);
    }
    ThreadCount(const ThreadCount&) = delete;
    ThreadCount& operator=(const ThreadCount&) = delete;

private:
    std::string old_;
};

}  // namespace lf::test
