#include "bake/snapshot_writer.h"

#include "util/stopwatch.h"

namespace lf {

SnapshotWriter::SnapshotWriter() : thread_([this] { run(); }) {}

SnapshotWriter::~SnapshotWriter() {
    {
        std::lock_guard<std::mutex> lock(mutex_);
        stopping_ = true;
    }
    wake_.notify_one();
    thread_.join();
}

void SnapshotWriter::submit(std::string output, int pass, SnapshotWrite write) {
    {
        std::lock_guard<std::mutex> lock(mutex_);
        tasks_.push_back({std::move(output), pass, std::move(write)});
    }
    wake_.notify_one();
}

bool SnapshotWriter::idle() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return tasks_.empty() && !busy_;
}

std::vector<SnapshotWriter::Written> SnapshotWriter::take_written() {
    std::lock_guard<std::mutex> lock(mutex_);
    if (failure_) std::rethrow_exception(std::exchange(failure_, nullptr));
    return std::exchange(written_, {});
}

std::vector<SnapshotWriter::Written> SnapshotWriter::drain() {
    {
        std::unique_lock<std::mutex> lock(mutex_);
        finished_.wait(lock, [this] { return tasks_.empty() && !busy_; });
    }
    return take_written();
}

void SnapshotWriter::run() {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
        wake_.wait(lock, [this] { return stopping_ || !tasks_.empty(); });
        if (tasks_.empty()) return;  // stopping, and nothing left to write
        Task task = std::move(tasks_.front());
        tasks_.pop_front();
        busy_ = true;
        lock.unlock();
        const Stopwatch clock;
        Written done{task.output, task.pass, {}, 0.0};
        std::exception_ptr failure;
        try {
            done.files = task.write();
        } catch (...) {
            failure = std::current_exception();
        }
        done.seconds = clock.seconds();
        lock.lock();
        busy_ = false;
        if (failure) {
            if (!failure_) failure_ = failure;
        } else {
            written_.push_back(std::move(done));
        }
        finished_.notify_all();
    }
}

}  // namespace lf
