// A byte queue of whole frames for the serial link: a frame goes in whole or not at all (dropped and
// counted), and the board takes out as much as its port accepts without blocking. One context writes and
// reads (the board's loop()); no locking.
#pragma once

#include <stddef.h>
#include <stdint.h>
#include <string.h>

namespace impactapp {

template <size_t kCapacity>
class TxQueue {
  static_assert((kCapacity & (kCapacity - 1)) == 0, "capacity must be a power of two");

 public:
  size_t used() const { return static_cast<size_t>(head_ - tail_); }
  size_t room() const { return kCapacity - used(); }

  // Appends the frame if it fits whole; else counts it dropped. True when queued.
  bool push(const uint8_t* data, size_t n) {
    if (n > room()) {
      ++dropped_frames_;
      dropped_bytes_ += static_cast<uint32_t>(n);
      return false;
    }
    const size_t at = head_ & (kCapacity - 1);
    const size_t first = n < kCapacity - at ? n : kCapacity - at;
    memcpy(buf_ + at, data, first);
    memcpy(buf_, data + first, n - first);
    head_ += n;
    return true;
  }

  // The queued bytes that lie contiguously at the front (0 when empty).
  size_t peek(const uint8_t** p) const {
    const size_t at = tail_ & (kCapacity - 1);
    const size_t n = used();
    *p = buf_ + at;
    return n < kCapacity - at ? n : kCapacity - at;
  }
  void consume(size_t n) { tail_ += n <= used() ? n : used(); }

  uint32_t dropped_frames() const { return dropped_frames_; }
  uint32_t dropped_bytes() const { return dropped_bytes_; }

 private:
  uint8_t buf_[kCapacity];
  size_t head_ = 0, tail_ = 0;  // free-running; their difference is the fill (wraps safely)
  uint32_t dropped_frames_ = 0, dropped_bytes_ = 0;
};

}  // namespace impactapp
