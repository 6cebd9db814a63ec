// Lock-free hand-over of the newest value from one producer thread to one consumer thread
// (the ARCHITECTURE's "immutable snapshot by pointer swap"): three slots, the producer writes
// its back slot and swaps it with the middle one; the consumer swaps the middle one with its
// front slot only when something new is there. Neither side ever waits for the other, and a
// slot is never read and written at the same time. T is allocated once, up front.
#pragma once
#include <atomic>
#include <cstdint>

namespace hh {

template <class T>
class TripleBuffer {
public:
    // Every slot starts as a copy of `initial`, so containers inside T keep their capacity.
    explicit TripleBuffer(const T& initial = T()) : slots_{initial, initial, initial} {}

    // Producer side: write into back(), then publish().
    T& back() { return slots_[back_]; }
    void publish() {
        const std::uint8_t old = middle_.exchange(static_cast<std::uint8_t>(back_ | kFresh), std::memory_order_acq_rel);
        back_ = old & kIndex;
    }

    // Consumer side: true when a newer value was published since the last call; front() is
    // then that value (and stays valid until the next fetch()).
    bool fetch() {
        if (!(middle_.load(std::memory_order_acquire) & kFresh)) return false;
        const std::uint8_t old = middle_.exchange(front_, std::memory_order_acq_rel);
        front_ = old & kIndex;
        return true;
    }
    const T& front() const { return slots_[front_]; }
    T& front_mutable() { return slots_[front_]; }

private:
    static constexpr std::uint8_t kIndex = 3, kFresh = 4;
    T slots_[3];
    std::uint8_t back_ = 0, front_ = 1;  // owned by producer and consumer respectively
    std::atomic<std::uint8_t> middle_{2};
};

}  // namespace hh
