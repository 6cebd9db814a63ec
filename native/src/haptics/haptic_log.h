// The haptic loop's record of itself: one row per haptic step, written by the haptic thread
// into a ring allocated up front and read by the host (Python) whenever it likes. Single
// producer, single consumer, and neither waits: when the ring is full because the reader
// fell behind, the producer drops the new row and counts it (it never overwrites a row the
// reader may be copying).
#pragma once
#include <algorithm>
#include <atomic>
#include <cstdint>
#include <vector>

#include "common/types.h"

namespace hh {

// A pose into 7 doubles: position, quaternion (x, y, z, s)
inline void put_pose(double* out, const Vec3& p, const Vec4& q) {
    for (int i = 0; i < 3; ++i) out[i] = p[i];
    for (int i = 0; i < 4; ++i) out[3 + i] = q[i];
}

// Columns of a row: time (s), period since the previous step (s), the step's own cost (s),
// device position (3) and quaternion (4), proxy position (3) and quaternion (4), feedback
// force (3, N) and torque (3, N m) sent to the device.
constexpr int kLogColumns = 23;

struct LogRow {
    double v[kLogColumns];
};

class HapticLog {
public:
    explicit HapticLog(std::size_t capacity = 1) : rows_(std::max<std::size_t>(capacity, 1)) {}
    std::size_t capacity() const { return rows_.size(); }
    // the ring's storage, for the haptic thread to lock in memory
    const void* storage() const { return rows_.data(); }
    std::size_t storage_bytes() const { return rows_.size() * sizeof(LogRow); }

    void push(const LogRow& row) {  // producer
        const std::uint64_t w = written_.load(std::memory_order_relaxed);
        if (w - read_.load(std::memory_order_acquire) >= rows_.size()) {
            dropped_.fetch_add(1, std::memory_order_relaxed);
            return;
        }
        rows_[w % rows_.size()] = row;
        written_.store(w + 1, std::memory_order_release);
    }
    // Consumer: copies up to max_rows unread rows into out (row-major); returns how many.
    std::size_t read(double* out, std::size_t max_rows) {
        const std::uint64_t w = written_.load(std::memory_order_acquire);
        std::uint64_t r = read_.load(std::memory_order_relaxed);
        std::size_t n = 0;
        for (; r < w && n < max_rows; ++r, ++n) {
            const LogRow& row = rows_[r % rows_.size()];
            std::copy(row.v, row.v + kLogColumns, out + n * kLogColumns);
        }
        read_.store(r, std::memory_order_release);
        return n;
    }
    std::uint64_t written() const { return written_.load(std::memory_order_acquire); }
    std::uint64_t unread() const { return written() - read_.load(std::memory_order_acquire); }
    std::uint64_t dropped() const { return dropped_.load(std::memory_order_relaxed); }

private:
    std::vector<LogRow> rows_;
    std::atomic<std::uint64_t> written_{0};
    std::atomic<std::uint64_t> read_{0};
    std::atomic<std::uint64_t> dropped_{0};
};

}  // namespace hh
