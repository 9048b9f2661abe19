// The job driver's writer thread: a snapshot is read back on the GL thread
// between passes, then built and written here while the passes go on, so
// intermediate files never stop the GPU (issue #12). The driver hands over
// one snapshot at a time (SnapshotSchedule asks for idle()) and collects
// what was written after each pass, to announce it.
#pragma once

#include "bake/progressive.h"

#include <condition_variable>
#include <deque>
#include <exception>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace lf {

class SnapshotWriter {
public:
    struct Written {
        std::string output;
        int pass = 0;
        std::vector<std::string> files;
        double seconds = 0.0;  // building and writing, on the writer thread
    };

    SnapshotWriter();
    // Finishes what was handed over, then stops (a failure there is dropped:
    // the job is already failing or done).
    ~SnapshotWriter();
    SnapshotWriter(const SnapshotWriter&) = delete;
    SnapshotWriter& operator=(const SnapshotWriter&) = delete;

    void submit(std::string output, int pass, SnapshotWrite write);
    // Nothing handed over is still being written.
    bool idle() const;
    // The snapshots written since the last call, oldest first. Rethrows the
    // failure of a write (a full disk), with the file's name in it.
    std::vector<Written> take_written();
    // Waits until everything handed over is written, then take_written().
    std::vector<Written> drain();

private:
    struct Task {
        std::string output;
        int pass;
        SnapshotWrite write;
    };
    void run();

    mutable std::mutex mutex_;
    std::condition_variable wake_, finished_;
    std::deque<Task> tasks_;
    bool busy_ = false, stopping_ = false;
    std::vector<Written> written_;
    std::exception_ptr failure_;
    std::thread thread_;  // last: starts once the members above exist
};

}  // namespace lf
