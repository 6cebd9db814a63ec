// Every allocation of the test program that includes this header (in one source file only: it
// replaces the global operator new) goes through here, so a test can count them around the
// haptic loop's calls. ThreadSanitizer needs its own operator new from the first instant, so its
// build does not count (the normal and AddressSanitizer builds do).
#pragma once
#include <atomic>
#include <cstdlib>
#include <new>

static std::atomic<long> g_allocations{0};
#if defined(__SANITIZE_THREAD__)
constexpr bool kCountsAllocations = false;
#else
constexpr bool kCountsAllocations = true;
void* operator new(std::size_t n) {
    g_allocations.fetch_add(1, std::memory_order_relaxed);
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {  // std::stable_sort's buffer, e.g.
    g_allocations.fetch_add(1, std::memory_order_relaxed);
    return std::malloc(n ? n : 1);
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, const std::nothrow_t&) noexcept { std::free(p); }
#endif
