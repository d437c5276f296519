// coefficient layouts and the cell operations of a step (sources, records, phasors, statistics)
// (part of the native kernels: included by lattice.cc, one translation unit)
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <optional>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace dl {

// ----------------------------------------------------------------------------------------------
// coefficient arrays broadcast to a grid: absent, one value (scalar), one value per row (n, 1),
// one vector for all rows (1, m), or a full array (n, m)

enum Mode : int { kAbsent = 0, kScalar = 1, kPerRow = 2, kPerCol = 3, kFull = 4 };

template <typename T>
struct Coef {
  const T* data = nullptr;
  int mode = kAbsent;
  int64_t ld = 0;  // row stride of a full array
  bool present() const { return mode != kAbsent; }
  bool in_register() const { return mode == kScalar || mode == kPerRow; }
  T value(int64_t i) const { return mode == kScalar ? data[0] : data[i]; }
  const T* row(int64_t i) const { return mode == kPerCol ? data : data + i * ld; }
  T at(int64_t i, int64_t j) const { return in_register() ? value(i) : row(i)[j]; }
};

template <typename T>
Coef<T> make_coef(const ffi::AnyBuffer& b, int64_t rows, int64_t cols, bool* ok) {
  Coef<T> c;
  auto d = b.dimensions();
  if (b.element_count() == 0) return c;
  c.data = reinterpret_cast<const T*>(b.untyped_data());
  // the narrowest layout that matches (a grid one cell wide has (n, 1) arrays: one value per row)
  if (d.size() == 0) {
    c.mode = kScalar;
  } else if (d.size() == 2 && d[0] == rows && d[1] == 1) {
    c.mode = kPerRow;
  } else if (d.size() == 2 && d[0] == 1 && d[1] == cols) {
    c.mode = kPerCol;
  } else if (d.size() == 2 && d[0] == rows && d[1] == cols) {
    c.mode = kFull;
    c.ld = cols;
  } else if (b.element_count() == 1) {
    c.mode = kScalar;
  } else {
    *ok = false;
  }
  return c;
}

template <typename T>
bool all_one(const T* v, int64_t n) {
  for (int64_t j = 0; j < n; ++j)
    if (v[j] != T(1)) return false;
  return true;
}

// ----------------------------------------------------------------------------------------------
// cell operations of a step (sources, recorded cells, phasors) bucketed by row, list order kept
// within a row; whole-field statistics (peak |p|, sum of p^2, first arrival)

struct RowIndex {
  std::vector<int64_t> start;  // (nx + 1,) offsets into `item`
  std::vector<int64_t> item;   // list indices grouped by row
  RowIndex(const int32_t* cells, int64_t n, int64_t nx) : start(nx + 1, 0), item(n) {
    for (int64_t k = 0; k < n; ++k) ++start[cells[2 * k] + 1];
    for (int64_t i = 0; i < nx; ++i) start[i + 1] += start[i];
    std::vector<int64_t> fill(start.begin(), start.end() - 1);
    for (int64_t k = 0; k < n; ++k) item[fill[cells[2 * k]]++] = k;
  }
};

template <typename T>
struct CellOps {
  int64_t ny = 0;
  const int32_t* src_cells = nullptr;  // sources, in list order: set (src_hard = 1) or add
  const int32_t* src_hard = nullptr;
  const T* src_vals = nullptr;  // (n_steps, n_src)
  int64_t n_src = 0;
  const int32_t* rec_cells = nullptr;  // recorded after the sources: rec_out (n_steps, n_rec)
  T* rec_out = nullptr;
  int64_t n_rec = 0;
  const int32_t* zero_cells = nullptr;  // then set to zero (the adjoint's hard sources)
  int64_t n_zero = 0;
  const int32_t* ph_cells = nullptr;  // phasors: re += p cos, im += p sin (per step tables)
  const T* ph_cos = nullptr;
  const T* ph_sin = nullptr;
  T* ph_re = nullptr;
  T* ph_im = nullptr;
  int64_t n_ph = 0;
  T* p_max = nullptr;  // whole-field statistics (nullptr: not recorded)
  T* p_sq = nullptr;
  int32_t* arrival = nullptr;
  T threshold = T(0);
  int64_t n0 = 0;  // steps done before this call (arrival records n0 + step)
};

template <typename T>
struct CellPlan {
  RowIndex src, rec, zer, pha;
  std::vector<char> busy;  // rows with any cell operation
  explicit CellPlan(const CellOps<T>& c, int64_t nx)
      : src(c.src_cells, c.n_src, nx), rec(c.rec_cells, c.n_rec, nx), zer(c.zero_cells, c.n_zero, nx),
        pha(c.ph_cells, c.n_ph, nx), busy(nx, 0) {
    for (const RowIndex* r : {&src, &rec, &zer, &pha})
      for (int64_t i = 0; i < nx; ++i) busy[i] |= r->start[i] != r->start[i + 1];
  }
};

// row i of step s (0-based in the call) of the leapfrog, on the new field nw; the cells of columns
// [col0, col1) only where col1 >= 0 (the 3-D kernel's bands of a plane)
template <typename T>
void leapfrog_cells(const CellOps<T>& c, const CellPlan<T>& pl, int64_t i, int64_t s, T* nw, int64_t col0 = 0,
                    int64_t col1 = -1) {
  const int64_t ny = c.ny;
  if (col1 < 0) col1 = ny;
  auto out = [&](const int32_t* cells, int64_t k) { return cells[2 * k + 1] < col0 || cells[2 * k + 1] >= col1; };
  for (int64_t u = pl.src.start[i]; u < pl.src.start[i + 1]; ++u) {
    const int64_t k = pl.src.item[u];
    if (out(c.src_cells, k)) continue;
    const int64_t at = i * ny + c.src_cells[2 * k + 1];
    const T v = c.src_vals[s * c.n_src + k];
    if (c.src_hard[k]) nw[at] = v;
    else nw[at] = nw[at] + v;
  }
  for (int64_t u = pl.rec.start[i]; u < pl.rec.start[i + 1]; ++u) {
    const int64_t k = pl.rec.item[u];
    if (out(c.rec_cells, k)) continue;
    c.rec_out[s * c.n_rec + k] = nw[i * ny + c.rec_cells[2 * k + 1]];
  }
  for (int64_t u = pl.zer.start[i]; u < pl.zer.start[i + 1]; ++u) {
    const int64_t k = pl.zer.item[u];
    if (out(c.zero_cells, k)) continue;
    nw[i * ny + c.zero_cells[2 * k + 1]] = T(0);
  }
  if (pl.pha.start[i] != pl.pha.start[i + 1]) {
    const T cs = c.ph_cos[s], sn = c.ph_sin[s];
    for (int64_t u = pl.pha.start[i]; u < pl.pha.start[i + 1]; ++u) {
      const int64_t k = pl.pha.item[u];
      if (out(c.ph_cells, k)) continue;
      const T v = nw[i * ny + c.ph_cells[2 * k + 1]];
      c.ph_re[k] = c.ph_re[k] + v * cs;
      c.ph_im[k] = c.ph_im[k] + v * sn;
    }
  }
}

// statistics of one row of the new field p (ny values), at step s; columns [j0, j1) of it where
// j1 >= 0 (p then points at the row's column 0 still)
template <typename T>
void row_stats(const CellOps<T>& c, int64_t i, int64_t s, const T* p, int64_t j0 = 0, int64_t j1 = -1) {
  const int64_t ny = c.ny;
  const int64_t lo = j0, hi = j1 < 0 ? ny : j1;
  if (c.p_max) {
    T* m = c.p_max + i * ny;
    for (int64_t j = lo; j < hi; ++j) {
      const T v = std::abs(p[j]);
      m[j] = (v > m[j] || v != v) ? v : m[j];  // jnp.maximum: NaN wins
    }
  }
  if (c.p_sq) {
    T* q = c.p_sq + i * ny;
    for (int64_t j = lo; j < hi; ++j) q[j] = q[j] + p[j] * p[j];
  }
  if (c.arrival) {
    int32_t* a = c.arrival + i * ny;
    const int32_t n_next = int32_t(c.n0 + s + 1);
    for (int64_t j = lo; j < hi; ++j)
      if (a[j] < 0 && std::abs(p[j]) > c.threshold) a[j] = n_next;
  }
}

}  // namespace dl
