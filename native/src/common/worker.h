// A second thread for the visual loop's world step. The step has parts that do not depend on
// each other (collision detection and the bodies' free solves; the bodies' contact responses),
// so with two cores the world runs them side by side: the caller starts a job here, does its
// own share, then joins. One job at a time; the thread sleeps in between.
//
// Not for the haptic loop: join() waits on the job, which is fine inside one visual step (it
// is the step's own work) but never allowed at 1 kHz.
#pragma once
#include <condition_variable>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>

namespace hh {

class Worker {
public:
    Worker();
    ~Worker();
    Worker(const Worker&) = delete;
    Worker& operator=(const Worker&) = delete;

    // Runs job on the worker thread. The previous job must have been joined.
    void start(std::function<void()> job);
    // Waits for the job; rethrows what it threw.
    void join();
    // Waits for the job and drops what it threw (for unwinding after the caller's own error).
    void join_quietly() noexcept;

private:
    void loop();
    std::mutex mutex_;
    std::condition_variable wake_, done_;
    std::function<void()> job_;
    bool busy_ = false, quit_ = false;
    std::exception_ptr error_;
    std::thread thread_;  // last: started once the members above exist
};

}  // namespace hh
