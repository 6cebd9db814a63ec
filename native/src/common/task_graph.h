// The parts of one visual step as a small graph of tasks run by the caller's thread and, when
// there is one, the world's worker thread (common/worker.h). A task runs once the tasks it
// comes after are done; of the tasks ready, the one of highest priority runs first; a task may
// add tasks while it runs (the contact solve's parts exist only once the contacts are known).
// Each thread takes the next ready task as soon as it is free, so whichever part of the step
// is longest (the hand's implicit solve, say) runs beside everything that does not need it.
// The tasks are milliseconds long: one mutex guards the graph.
#pragma once
#include <condition_variable>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <vector>

#include "common/worker.h"

namespace hh {

class TaskGraph {
public:
    // Returns the task's index (for `after` of later tasks); `after` names tasks added before
    // (std::invalid_argument otherwise). Safe to call from a running task.
    int add(std::function<void()> run, std::vector<int> after, double priority);
    // Runs every task, those added meanwhile included, on this thread and the worker (if not
    // null); returns once all are done. A task that throws stops both threads from taking more
    // and its exception is rethrown here, once the worker has stopped too.
    void run(Worker* worker);
    // From inside a running task: `other` becomes a task of the given priority that a free
    // thread may take, while this thread runs `mine`; if no thread has taken `other` by then,
    // this thread runs it too. Returns once both are done, rethrowing what either threw (mine's
    // first). The jobs must not wait on other tasks.
    void run_beside(const std::function<void()>& mine, const std::function<void()>& other, double priority);

private:
    struct Task {
        std::function<void()> run;
        std::vector<int> after;
        double priority;
        int state = 0;  // 0 waiting, 1 running, 2 done
    };
    void drain();  // each thread's loop
    // runs a task taken by this thread (lock held on entry and exit, released while it runs)
    void run_task(std::unique_lock<std::mutex>& lock, Task& task);
    std::mutex mutex_;
    std::condition_variable changed_;
    std::deque<Task> tasks_;  // (a deque: a running task's entry stays put while others are added)
    int left_ = 0, running_ = 0;
    std::exception_ptr error_;
};

}  // namespace hh
