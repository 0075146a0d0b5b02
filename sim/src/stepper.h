// The stepper's data layout and its fused pass over the whole plate (one central-difference step), shared by
// the plate's run and its sub-cycled patches (run.cpp). Multiversioned (target_clones) in stepper.cpp.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "impactsim.h"
#include "sweep.h"

namespace impactsim {
namespace detail {

// d and beta are stored row by row (6 rs floats a row), block-interleaved [16-node block][d w, bx, by |
// beta w, bx, by][16]: node i, field f at db_index(i, f), its beta kDbBeta further on.
constexpr int kDbBeta = 48;
inline size_t db_index(int64_t i, int f) { return static_cast<size_t>((i / 16) * 96 + f * 16 + i % 16); }

// zero-initialised, 64-byte aligned. The storage of a run's buffers is kept per thread for the next run of
// the thread (a batch of short runs, e.g. the contact windows, would otherwise fault fresh pages in each time).
struct AlignedFloats {
  std::vector<float> raw;
  float* p;
  explicit AlignedFloats(size_t n) {
    std::vector<std::vector<float>>& pool = spare();
    for (size_t k = 0; k < pool.size(); ++k)
      if (pool[k].capacity() >= n + 16) {
        raw.swap(pool[k]);
        pool.erase(pool.begin() + static_cast<std::ptrdiff_t>(k));
        break;
      }
    raw.assign(n + 16, 0.0f);
    const size_t mis = reinterpret_cast<uintptr_t>(raw.data()) % 64;
    p = raw.data() + (mis ? (64 - mis) / sizeof(float) : 0);
  }
  ~AlignedFloats() {
    std::vector<std::vector<float>>& pool = spare();
    if (pool.size() < kSpare && raw.capacity() > 0) pool.push_back(std::move(raw));
  }
  AlignedFloats(const AlignedFloats&) = delete;
  AlignedFloats& operator=(const AlignedFloats&) = delete;

 private:
  static constexpr size_t kSpare = 8;  // a run holds 4 (and 3 per sub-cycled patch)
  static std::vector<std::vector<float>>& spare() {
    thread_local std::vector<std::vector<float>> pool;
    return pool;
  }
};

// The stepper's pass: internal forces and the central-difference update of a row as soon as it is complete,
//   d_{n+1/2} = alpha d_{n-1/2} - beta f,  u_{n+1} = u_n + d_{n+1/2}   (d = dt v, beta = dt^2 c2 / m, 0 at
// fixed dofs and padding). External loads are added afterwards (they do not enter this step's internal forces).
struct StepArgs {
  int nx, ny;
  int64_t rs;         // row stride of the state arrays (padded: a multiple of 16 floats, one block to spare)
  size_t np;          // field stride, (ny + 1) * rs
  const Coef<float>* base;
  const Plate::Special* special;
  const int64_t* row_start;
  float* u;           // [w | bx | by], 64-byte aligned rows
  float* db;          // d and beta, rows of 6 rs floats, block-interleaved (db_index)
  float alpha;
  Accumulators<float>* acc;  // portable path
  float* edge;               // fused path: 2 x 6 edge arrays of rs floats, block-interleaved (zero beyond nx)
  const int64_t* scaled_row;     // fused path: per element row, index into the scale tables or -1
  const uint8_t* scaled_block;   // [scaled row][16-element block]: 1 if the block holds a special element
  const float* scale;            // [scaled row][D / D0 (rs floats), S / S0 (rs floats)]
  int64_t nblocks;
  // fused path: the node rows to step, j_lo..j_hi (clipped to 0..ny; none when j_lo > j_hi). Rows outside
  // must be at rest (u = d = 0): their forces are then zero, so skipping them gives the same floats.
  int j_lo = 0, j_hi = 1 << 30;
  int b_lo = 0, b_hi = 1 << 30;  // likewise the 16-node blocks of each row (node i in block i / 16)
};

void step_fast(const StepArgs& a);

// True if every value is finite.
bool all_finite(const float* x, size_t n);

}  // namespace detail
}  // namespace impactsim
