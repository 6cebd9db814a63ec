#include "haptics/realtime.h"

#include <dlfcn.h>
#include <link.h>
#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstring>

namespace hh {

namespace {
// The CPUs in the kernel's isolcpus= list (/sys/devices/system/cpu/isolated, e.g. "2-3,5").
cpu_set_t isolated_cpus() {
    cpu_set_t set;
    CPU_ZERO(&set);
    std::FILE* f = std::fopen("/sys/devices/system/cpu/isolated", "r");
    if (!f) return set;
    int a = 0, b = 0;
    char sep = 0;
    while (std::fscanf(f, "%d", &a) == 1) {
        b = a;
        if (std::fscanf(f, "%c", &sep) == 1 && sep == '-' && std::fscanf(f, "%d", &b) == 1) std::fscanf(f, "%c", &sep);
        for (int c = a; c <= b && c < CPU_SETSIZE; ++c) CPU_SET(c, &set);
    }
    std::fclose(f);
    return set;
}

// The CPU to pin to, -1 for none; `isolated` tells whether it is an isolated one.
int choose_cpu(bool priority, bool& isolated) {
    cpu_set_t allowed;
    if (sched_getaffinity(0, sizeof allowed, &allowed) != 0) return -1;
    const cpu_set_t iso = isolated_cpus();
    for (int c = 0; c < CPU_SETSIZE; ++c)
        if (CPU_ISSET(c, &iso)) {  // the user set one aside for us (the default mask leaves it out)
            isolated = true;
            return c;
        }
    if (!priority) return -1;  // an ordinary thread is better off where the scheduler finds room
    for (int c = CPU_SETSIZE - 1; c >= 0; --c)
        if (CPU_ISSET(c, &allowed)) return c;
    return -1;
}

bool pin(int cpu) {
    cpu_set_t one;
    CPU_ZERO(&one);
    CPU_SET(cpu, &one);
    return pthread_setaffinity_np(pthread_self(), sizeof one, &one) == 0;
}

// Whole pages around [p, p + n).
void page_span(const void* p, std::size_t n, void*& begin, std::size_t& bytes) {
    const std::uintptr_t page = static_cast<std::uintptr_t>(sysconf(_SC_PAGESIZE));
    const std::uintptr_t a = reinterpret_cast<std::uintptr_t>(p) & ~(page - 1);
    const std::uintptr_t b = (reinterpret_cast<std::uintptr_t>(p) + n + page - 1) & ~(page - 1);
    begin = reinterpret_cast<void*>(a);
    bytes = b - a;
}

bool lock(const void* p, std::size_t n) {
    void* begin;
    std::size_t bytes;
    page_span(p, n, begin, bytes);
    return mlock(begin, bytes) == 0;
}

void unlock(const void* p, std::size_t n) {
    void* begin;
    std::size_t bytes;
    page_span(p, n, begin, bytes);
    munlock(begin, bytes);
}

// The segments (code, constants, data) of the loaded object that holds `code`: a page of it the
// loop touched first, code first run or a constant first read, would be a page fault there.
struct CodeSearch {
    const void* base;
    double locked = 0, refused = 0;
};

int lock_code_segments(dl_phdr_info* info, size_t, void* data) {
    auto* search = static_cast<CodeSearch*>(data);
    if (reinterpret_cast<const void*>(info->dlpi_addr) != search->base) return 0;
    for (int i = 0; i < info->dlpi_phnum; ++i) {
        const ElfW(Phdr)& ph = info->dlpi_phdr[i];
        if (ph.p_type != PT_LOAD) continue;
        const void* begin = reinterpret_cast<const void*>(info->dlpi_addr + ph.p_vaddr);
        (lock(begin, ph.p_memsz) ? search->locked : search->refused) += static_cast<double>(ph.p_memsz);
    }
    return 1;
}

void lock_code_of(const void* code, LoopSetup& s) {
    Dl_info where{};
    if (!dladdr(code, &where) || !where.dli_fbase) return;
    // dl_iterate_phdr names objects by their load bias, dladdr by their lowest address: for the
    // shared objects here (first segment at vaddr 0) they are the same; a mismatch locks nothing
    CodeSearch search{where.dli_fbase};
    dl_iterate_phdr(&lock_code_segments, &search);
    s.locked_bytes += search.locked;
    s.unlocked_bytes += search.refused;
}

// Touches and locks `bytes` of stack below the caller's frame: the loop's calls then run on
// pages that are already there. Not inlined, so its frame is below the loop's.
// Returns where the block was (as a number: the pages stay, the frame does not).
__attribute__((noinline)) std::uintptr_t fault_in_stack(std::size_t bytes, bool& locked) {
    unsigned char* block = static_cast<unsigned char*>(alloca(bytes));
    std::memset(block, 0, bytes);
    asm volatile("" : : "r"(block) : "memory");  // keep the writes
    locked = lock(block, bytes);
    return reinterpret_cast<std::uintptr_t>(block);
}
}  // namespace

LoopSetup set_up_loop_thread(bool realtime, int priority, std::size_t stack_bytes, const MemoryRange* ranges, int n_ranges,
                             const void* const* code, int n_code) {
    LoopSetup s;
    if (realtime) {
        sched_param sp{};
        sp.sched_priority = std::min(priority, sched_get_priority_max(SCHED_FIFO));
        s.priority = pthread_setschedparam(pthread_self(), SCHED_FIFO, &sp) == 0;
    }
    bool isolated = false;
    const int cpu = choose_cpu(s.priority, isolated);
    if (cpu >= 0 && pin(cpu)) {
        s.cpu = cpu;
        s.cpu_isolated = isolated;
    }
    bool locked = false;
    s.stack = fault_in_stack(stack_bytes, locked);
    s.stack_bytes = stack_bytes;
    (locked ? s.locked_bytes : s.unlocked_bytes) += static_cast<double>(stack_bytes);
    for (int i = 0; i < n_ranges; ++i)
        (lock(ranges[i].begin, ranges[i].bytes) ? s.locked_bytes : s.unlocked_bytes) += static_cast<double>(ranges[i].bytes);
    for (int i = 0; i < n_code; ++i) lock_code_of(code[i], s);
    return s;
}

void release_loop_memory(const LoopSetup& setup, const MemoryRange* ranges, int n_ranges) {
    if (setup.stack) unlock(reinterpret_cast<const void*>(setup.stack), setup.stack_bytes);
    for (int i = 0; i < n_ranges; ++i) unlock(ranges[i].begin, ranges[i].bytes);
}

void thread_page_faults(double& minor, double& major) {
    rusage u{};
    getrusage(RUSAGE_THREAD, &u);
    minor = static_cast<double>(u.ru_minflt);
    major = static_cast<double>(u.ru_majflt);
}

}  // namespace hh
