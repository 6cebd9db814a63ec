// What a live haptic thread does for itself before its first deadline, so that nothing but the
// device's own I/O and the sleep to the next deadline costs time in the loop: real-time priority,
// one CPU of its own, its memory locked (no page faults), its stack faulted in. Each step fails
// soft: without the privilege the loop runs as an ordinary thread, and the report says so.
#pragma once
#include <cstddef>
#include <cstdint>

namespace hh {

struct LoopSetup {
    bool priority = false;       // SCHED_FIFO granted (root, CAP_SYS_NICE or an rtprio limit)
    int cpu = -1;                // the CPU the thread is pinned to, -1: not pinned
    bool cpu_isolated = false;   // that CPU is in the kernel's isolcpus list
    double locked_bytes = 0;     // memory of the loop locked in RAM (mlock)
    double unlocked_bytes = 0;   // memory of the loop mlock refused (RLIMIT_MEMLOCK)
    std::uintptr_t stack = 0;    // where the stack was faulted in and locked (release_loop_memory unlocks it)
    std::size_t stack_bytes = 0;
};

struct MemoryRange {
    const void* begin = nullptr;
    std::size_t bytes = 0;
};

// Run on the haptic thread itself: asks for SCHED_FIFO at `priority` (when `realtime`), pins
// the thread (to the first isolated CPU the process may use, else, with real-time priority, to
// the last CPU it may use; an ordinary thread is left free to move), faults in and locks
// `stack_bytes` of its stack, every range given, and the segments (code, constants, data) of the
// loaded objects that hold the functions `code` (this library, the maths and C libraries): a page
// of code first run or a constant first read inside the loop would be a page fault there. Those
// stay locked until the process ends (a few MB; another session may be using them).
LoopSetup set_up_loop_thread(bool realtime, int priority, std::size_t stack_bytes, const MemoryRange* ranges, int n_ranges,
                             const void* const* code, int n_code);
// Unlocks what set_up_loop_thread locked.
void release_loop_memory(const LoopSetup& setup, const MemoryRange* ranges, int n_ranges);

// Page faults of the calling thread so far (minor, major): the loop reads them around itself.
void thread_page_faults(double& minor, double& major);

}  // namespace hh
