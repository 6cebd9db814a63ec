#include "common/task_graph.h"

#include <stdexcept>

namespace hh {

namespace {
// runs f; what it throws, as a value
std::exception_ptr caught(const std::function<void()>& f) {
    try {
        f();
    } catch (...) {
        return std::current_exception();
    }
    return nullptr;
}
}  // namespace

int TaskGraph::add(std::function<void()> run, std::vector<int> after, double priority) {
    std::lock_guard<std::mutex> lock(mutex_);
    // (so the graph has no cycles: every task can run once those before it have)
    for (int a : after)
        if (a < 0 || a >= static_cast<int>(tasks_.size()))
            throw std::invalid_argument("TaskGraph::add: a task can only come after tasks added before it");
    tasks_.push_back(Task{std::move(run), std::move(after), priority});
    ++left_;
    changed_.notify_all();
    return static_cast<int>(tasks_.size()) - 1;
}

void TaskGraph::drain() {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
        if (error_ || left_ == 0) return;
        int best = -1;
        for (size_t i = 0; i < tasks_.size(); ++i) {
            const Task& t = tasks_[i];
            if (t.state != 0 || (best >= 0 && t.priority <= tasks_[best].priority)) continue;
            bool ready = true;
            for (int a : t.after) ready = ready && tasks_[a].state == 2;
            if (ready) best = static_cast<int>(i);
        }
        if (best < 0) {
            if (running_ == 0) {  // (cannot happen: add keeps the graph acyclic)
                error_ = std::make_exception_ptr(std::logic_error("TaskGraph: tasks wait on tasks that never run"));
                changed_.notify_all();
                return;
            }
            changed_.wait(lock);
            continue;
        }
        run_task(lock, tasks_[best]);
    }
}

void TaskGraph::run_task(std::unique_lock<std::mutex>& lock, Task& task) {
    task.state = 1;
    ++running_;
    lock.unlock();
    const std::exception_ptr error = caught(task.run);
    lock.lock();
    --running_;
    task.state = 2;
    --left_;
    if (error && !error_) error_ = error;
    changed_.notify_all();
}

void TaskGraph::run_beside(const std::function<void()>& mine, const std::function<void()>& other, double priority) {
    std::exception_ptr other_error;  // (written by whichever thread runs `other`, read after it is done)
    int id;
    {
        std::lock_guard<std::mutex> lock(mutex_);
        tasks_.push_back(Task{[&other, &other_error] { other_error = caught(other); }, {}, priority});
        ++left_;
        id = static_cast<int>(tasks_.size()) - 1;
        changed_.notify_all();
    }
    const std::exception_ptr mine_error = caught(mine);
    std::unique_lock<std::mutex> lock(mutex_);
    Task& task = tasks_[id];  // (a deque: the entry stays put while others are added)
    if (task.state == 0) run_task(lock, task);  // nobody took it: run it here
    else changed_.wait(lock, [&task] { return task.state == 2; });
    lock.unlock();
    if (mine_error) std::rethrow_exception(mine_error);
    if (other_error) std::rethrow_exception(other_error);
}

void TaskGraph::run(Worker* worker) {
    if (worker) worker->start([this] { drain(); });
    drain();
    if (worker) worker->join_quietly();  // (drain catches what the tasks throw)
    if (error_) std::rethrow_exception(error_);
}

}  // namespace hh
