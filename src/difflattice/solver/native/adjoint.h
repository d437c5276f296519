// the lattice adjoint's backward pass over one chunk with the coefficients' cotangents
// (part of the native kernels: included by lattice.cc, one translation unit)
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <optional>
#include <vector>

#include "cells.h"
#include "threads.h"

namespace dl {

// ----------------------------------------------------------------------------------------------
// the lattice adjoint's backward pass over one chunk, with the cotangents of the coefficients
// (solver/adjoint.py; leapfrog lattices without q_scale, keep, sponge or viscous term, 5-point
// stencil). The leapfrog is reversible: from the chunk's last two fields (p(n1), p(n1 - 1), saved
// by the forward run) each backward step also steps the forward field back,
//   p(n - 2) = 2 p(n - 1) - (p(n) - s(n)) + K L(p(n - 1))     (s: the soft sources' values; hard
//                                                               cells set to their values)
// so nothing per step is stored and the rounding of the reconstruction restarts from exact saved
// fields every chunk. Fused per row with it: the adjoint step and the cotangents at (a(n), p(n-1)),
//   x' = 2 x + L(u) - h,  u = K x              (x = a / V, V the ring volumes; 1 on a plane grid)
//   dK  += V x L(p)
//   dbx += -V (p_i - p_(i-1)) (u_i - u_(i-1))   per x face (nx + 1 of them per column)
//   dby += -A (p_j - p_(j-1)) (u_j - u_(j-1))   per y face (A the ring face areas; 1 on a plane grid)
// L(f) = bx_(i+1) (f_(i+1) - f) - bx_i (f - f_(i-1)) + mh by_(j+1) (f_(j+1) - f) - ml by_j (f - f_(j-1)),
// zero beyond the window; full face arrays; mh = A_(j+1) / V_j, ml = A_j / V_j (ones on a plane).

template <typename T>
struct AdjointChunkArgs {
  int64_t nx = 0, ny = 0, len = 0;
  int n_threads = 1, levels = 1;
  const T* p_end = nullptr;  // p(n1), n1 = n0 + len
  const T* pp_end = nullptr;  // p(n1 - 1)
  T* x = nullptr;  // the adjoint pair (x, h), in place
  T* h = nullptr;
  Coef<T> K;
  const T *bx = nullptr, *by = nullptr, *ml = nullptr, *mh = nullptr, *vol = nullptr, *area = nullptr;
  const int32_t* src_cells = nullptr;  // the forward sources: set (src_hard = 1) or add
  const int32_t* src_hard = nullptr;
  const T* src_vals = nullptr;  // (len + 2, n_src): steps n0 - 1 .. n1 (zero rows for steps <= 0)
  int64_t n_src = 0;
  CellOps<T> adj;  // the injected output cotangents (rows = the backward steps), records, zero cells
  T *dK = nullptr, *dbx = nullptr, *dby = nullptr;  // accumulated cotangents (nullptr: not wanted)
};

template <typename T, bool DK, bool DBX, bool DBY, bool RZ>
void adjoint_chunk_run(const AdjointChunkArgs<T>& a) {
  const int64_t nx = a.nx, ny = a.ny, len = a.len, cells = nx * ny;
  // the forward pair, stepped back in place: a buffer kept between calls (a fresh one would cost
  // its page faults on every call), one per calling thread
  thread_local std::vector<T> pbuf;
  if (pbuf.size() < size_t(2 * cells)) pbuf.resize(size_t(2 * cells));
  std::memcpy(pbuf.data(), a.p_end, sizeof(T) * cells);
  std::memcpy(pbuf.data() + cells, a.pp_end, sizeof(T) * cells);
  const RowIndex srcs(a.src_cells, a.n_src, nx);
  const CellPlan<T> aplan(a.adj, nx);
  const std::vector<T> zero(ny, T(0));
  const int levels = std::max(1, a.levels);
  T* xs[2] = {a.x, a.h};
  T* ps[2] = {pbuf.data(), pbuf.data() + cells};
  // step s (0-based) takes (a(n), a(n + 1)) to (a(n - 1), a(n)) and (p(n), p(n - 1)) to
  // (p(n - 1), p(n - 2)), n = n1 - s, in place in the pairs' buffers (as the leapfrog: row i of
  // step s overwrites what only rows i - 1 .. i + 1 of step s - 1 read); its cotangents pair a(n)
  // with p(n - 1). The pipeline of `leapfrog` (temporal blocking) schedules the rows.
  auto make_worker = [&](int) {
    struct Level {
      std::vector<T> ring;
      T* u[3];
    };
    std::vector<Level> lv(levels);
    for (auto& l : lv) l.ring.assign(3 * ny, T(0));
    std::vector<T> kreg(ny);
    return [&, lv = std::move(lv), kreg = std::move(kreg)](
               int l, int64_t L, int64_t i) mutable {
      const int64_t s = L - 1;
      const T* xb = xs[s & 1];
      T* hb = xs[(s + 1) & 1];
      T* p0 = ps[s & 1];  // p(n), overwritten by p(n - 2)
      const T* p1 = ps[(s + 1) & 1];  // p(n - 1)
      auto k_row = [&](int64_t r) -> const T* {
        if (!a.K.in_register()) return a.K.row(r);
        std::fill(kreg.begin(), kreg.end(), a.K.value(r));
        return kreg.data();
      };
      auto u_of = [&](int64_t r, T* dst) {
        if (r < 0 || r >= nx) {
          std::fill(dst, dst + ny, T(0));
          return;
        }
        const T* kr = k_row(r);
        const T* xr = xb + r * ny;
        for (int64_t j = 0; j < ny; ++j) dst[j] = kr[j] * xr[j];
      };
      Level& S = lv[l];
      if (i == 0) {
        S.u[0] = S.ring.data();
        S.u[1] = S.ring.data() + ny;
        S.u[2] = S.ring.data() + 2 * ny;
        std::fill(S.u[0], S.u[0] + ny, T(0));
        u_of(0, S.u[1]);
      } else {
        std::swap(S.u[0], S.u[1]);
        std::swap(S.u[1], S.u[2]);
      }
      u_of(i + 1, S.u[2]);
      const T* __restrict um = S.u[0];
      const T* __restrict u0 = S.u[1];
      const T* __restrict up = S.u[2];
      const T* s_n = a.src_vals + (len + 1 - s) * a.n_src;  // step n
      const T* s_nn = a.src_vals + (len - 1 - s) * a.n_src;  // step n - 2
      const T* __restrict bxl = a.bx + i * ny;
      const T* __restrict bxh = a.bx + (i + 1) * ny;
      const T* __restrict byr = a.by + i * (ny + 1);
      const T* __restrict pr = p1 + i * ny;
      const T* __restrict pm = i > 0 ? pr - ny : zero.data();
      const T* __restrict pq = i + 1 < nx ? pr + ny : zero.data();
      T* __restrict pn = p0 + i * ny;
      for (int64_t u = srcs.start[i]; u < srcs.start[i + 1]; ++u) {  // p(n) without step n's soft sources
        const int64_t k = srcs.item[u];
        if (!a.src_hard[k]) pn[a.src_cells[2 * k + 1]] -= s_n[k];
      }
      const T* __restrict x0 = xb + i * ny;
      const T* __restrict kr = k_row(i);
      // the ring metric (RZ), else unit factors that the compiler folds away
      const T* __restrict ml = a.ml;
      const T* __restrict mh = a.mh;
      const T* __restrict vol = a.vol;
      const T* __restrict area = a.area;
      auto ML = [&](int64_t j) { if constexpr (RZ) return ml[j]; else return T(1); };
      auto MH = [&](int64_t j) { if constexpr (RZ) return mh[j]; else return T(1); };
      auto VOL = [&](int64_t j) { if constexpr (RZ) return vol[j]; else return T(1); };
      auto AREA = [&](int64_t j) { if constexpr (RZ) return area[j]; else return T(1); };
      T* __restrict hr = hb + i * ny;
      T* __restrict dK = DK ? a.dK + i * ny : nullptr;
      T* __restrict dbx = DBX ? a.dbx + i * ny : nullptr;  // face i: rows i - 1, i
      T* __restrict dby = DBY ? a.dby + i * (ny + 1) : nullptr;
      // one cell: L(p(n - 1)), L(u), the cotangents, p(n - 2) and the adjoint step, in one pass
      // (ps, pn_, us, un: the low and high y neighbours of p(n - 1) and u)
      auto cell = [&](int64_t j, T ps, T pn_, T us, T un) {
        const T q = pr[j], w = u0[j];
        const T lp = (bxh[j] * (pq[j] - q) - bxl[j] * (q - pm[j])) + (MH(j) * byr[j + 1] * (pn_ - q) - ML(j) * byr[j] * (q - ps));
        const T lu = (bxh[j] * (up[j] - w) - bxl[j] * (w - um[j])) + (MH(j) * byr[j + 1] * (un - w) - ML(j) * byr[j] * (w - us));
        if constexpr (DK) dK[j] += VOL(j) * x0[j] * lp;
        if constexpr (DBX) dbx[j] += -VOL(j) * (q - pm[j]) * (w - um[j]);
        if constexpr (DBY) dby[j] += -AREA(j) * (q - ps) * (w - us);
        pn[j] = (T(2) * q - pn[j]) + kr[j] * lp;
        hr[j] = (T(2) * x0[j] + lu) - hr[j];
      };
      if (ny == 1) {
        cell(0, T(0), T(0), T(0), T(0));
      } else {
        cell(0, T(0), pr[1], T(0), u0[1]);
#pragma GCC ivdep
        for (int64_t j = 1; j < ny - 1; ++j) {  // the same as `cell`, written out so that it vectorises
          const T q = pr[j], w = u0[j];
          const T lp = (bxh[j] * (pq[j] - q) - bxl[j] * (q - pm[j])) +
                       (MH(j) * byr[j + 1] * (pr[j + 1] - q) - ML(j) * byr[j] * (q - pr[j - 1]));
          const T lu = (bxh[j] * (up[j] - w) - bxl[j] * (w - um[j])) +
                       (MH(j) * byr[j + 1] * (u0[j + 1] - w) - ML(j) * byr[j] * (w - u0[j - 1]));
          if constexpr (DK) dK[j] += VOL(j) * x0[j] * lp;
          if constexpr (DBX) dbx[j] += -VOL(j) * (q - pm[j]) * (w - um[j]);
          if constexpr (DBY) dby[j] += -AREA(j) * (q - pr[j - 1]) * (w - u0[j - 1]);
          pn[j] = (T(2) * q - pn[j]) + kr[j] * lp;
          hr[j] = (T(2) * x0[j] + lu) - hr[j];
        }
        cell(ny - 1, pr[ny - 2], T(0), u0[ny - 2], T(0));
      }
      if constexpr (DBY) dby[ny] += -AREA(ny) * (T(0) - pr[ny - 1]) * (T(0) - u0[ny - 1]);  // the last face
      if constexpr (DBX) {
        if (i == nx - 1) {  // face nx: row nx - 1 and the zero beyond
          T* e = a.dbx + nx * ny;
          for (int64_t j = 0; j < ny; ++j) e[j] += -VOL(j) * (T(0) - pr[j]) * (T(0) - u0[j]);
        }
      }
      for (int64_t u = srcs.start[i]; u < srcs.start[i + 1]; ++u) {
        const int64_t k = srcs.item[u];
        if (a.src_hard[k]) pn[a.src_cells[2 * k + 1]] = s_nn[k];
      }
      if (aplan.busy[i]) leapfrog_cells(a.adj, aplan, i, s, hb);
    };
  };
  auto finish = [&](int t, int nt) {  // an odd number of steps leaves the latest x in the h buffer
    if (len % 2 == 0) return;
    const int64_t r0 = nx * t / nt, r1 = nx * (t + 1) / nt;
    for (int64_t i = r0; i < r1; ++i) std::swap_ranges(a.x + i * ny, a.x + (i + 1) * ny, a.h + i * ny);
  };
  pipeline(nx, ny, len, std::max(1, a.n_threads), levels, make_worker, finish);
}

template <typename T>
void adjoint_chunk(const AdjointChunkArgs<T>& a) {
  const int w = (a.dK ? 4 : 0) | (a.dbx ? 2 : 0) | (a.dby ? 1 : 0);
  switch (w) {
#define DL_W(N, A, B, C)                              \
  case N:                                             \
    if (a.ml) return adjoint_chunk_run<T, A, B, C, true>(a); \
    return adjoint_chunk_run<T, A, B, C, false>(a);
    DL_W(0, false, false, false)
    DL_W(1, false, false, true)
    DL_W(2, false, true, false)
    DL_W(3, false, true, true)
    DL_W(4, true, false, false)
    DL_W(5, true, false, true)
    DL_W(6, true, true, false)
    DL_W(7, true, true, true)
#undef DL_W
  }
}

}  // namespace dl
