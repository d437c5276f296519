// the 3-D leapfrog over a block of steps: the 7-point flux stencil of lattice.operators on a volume,
// x planes as the pipeline's rows (temporal blocking, threads), sources and sensors per plane
// (part of the native kernels: included by volume.cc)
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include "cells.h"
#include "threads.h"

namespace dl {

// the step of the JAX 3-D loop (solver.stepper, standard stencil):
//   P(n+1) = 2 P(n) - P(n-1) + K L(P(n))              (no sponge)
//   P(n+1) = (2 P(n) - (1 - s) P(n-1) + K L(P(n))) / (1 + s)   (sponge s)
// then P(n+1) *= keep (soft cells), then the sources, then the records. L sums the axes in order
// x, y, z; an axis term is (q_hi + q_lo) - 2 q on unit faces (a closed window side: the ghost is the
// cell itself, a zero flux; an open or soft side: the ghost is 0), b_hi (q_hi - q) - b_lo (q - q_lo)
// with face conductances (every outer face's conductance carries its side, the ghosts are 0)
template <typename T>
struct VolumeArgs {
  int64_t nx, ny, nz, n_steps;
  int n_threads, levels;
  T* p;   // P(t) in, the latest field out
  T* pp;  // P(t-1) in, the previous field out
  const T* K = nullptr;  // full (nx, ny, nz) or nullptr: the scalar k
  T k = T(1);
  const T* bx = nullptr;  // (nx + 1, ny, nz), (nx, ny + 1, nz), (nx, ny, nz + 1), or all nullptr: unit faces
  const T* by = nullptr;
  const T* bz = nullptr;
  const T* keep = nullptr;    // (nx, ny, nz) or nullptr
  const T* sponge = nullptr;  // (nx, ny, nz) or nullptr
  bool closed[6] = {false, false, false, false, false, false};  // unit faces: x_lo x_hi y_lo y_hi z_lo z_hi rigid
  CellOps<T> cells;  // cells as (plane i, j nz + k): the plane is the pipeline's row
};

// the pointers of one row (i, j, :) of a step
template <typename T>
struct VolRow {
  const T *c, *xm, *xp, *ym, *yp;  // P(n) at the row and its four neighbour rows (a ghost row where outside)
  const T *bxl, *bxh, *byl, *byh, *bz;  // face conductances (FACES): low and high faces, z faces (nz + 1)
  const T* kr;                          // K of the row (KFULL)
  const T* sr;                          // sponge of the row (SPONGE)
  T* o;                                 // P(n-1) in, P(n+1) out
};

template <typename T, bool FACES, bool KFULL, bool SPONGE>
inline void volume_row(const VolRow<T>& r, int64_t nz, T k, bool zlo, bool zhi) {
  const T* __restrict c = r.c;
  const T* __restrict xm = r.xm;
  const T* __restrict xp = r.xp;
  const T* __restrict ym = r.ym;
  const T* __restrict yp = r.yp;
  T* __restrict o = r.o;
  auto cell = [&](int64_t j, T zm, T zp) __attribute__((always_inline)) {
    const T q = c[j];
    T lap;
    if constexpr (FACES) {
      const T tx = r.bxh[j] * (xp[j] - q) - r.bxl[j] * (q - xm[j]);
      const T ty = r.byh[j] * (yp[j] - q) - r.byl[j] * (q - ym[j]);
      const T tz = r.bz[j + 1] * (zp - q) - r.bz[j] * (q - zm);
      lap = (tx + ty) + tz;
    } else {
      const T tx = (xp[j] + xm[j]) - T(2) * q;
      const T ty = (yp[j] + ym[j]) - T(2) * q;
      const T tz = (zp + zm) - T(2) * q;
      lap = (tx + ty) + tz;
    }
    T kk = k;
    if constexpr (KFULL) kk = r.kr[j];
    const T d = kk * lap;
    if constexpr (SPONGE) {
      const T s = r.sr[j];
      o[j] = ((T(2) * q - (T(1) - s) * o[j]) + d) / (T(1) + s);
    } else {
      o[j] = (T(2) * q - o[j]) + d;
    }
  };
  // ghosts along z: 0 (open, soft or face conductances), the cell itself (a closed side, unit faces)
  const bool glo = !FACES && zlo, ghi = !FACES && zhi;
  if (nz == 1) {
    cell(0, glo ? c[0] : T(0), ghi ? c[0] : T(0));
    return;
  }
  cell(0, glo ? c[0] : T(0), c[1]);
#pragma GCC ivdep
  for (int64_t j = 1; j < nz - 1; ++j) cell(j, c[j - 1], c[j + 1]);
  cell(nz - 1, c[nz - 2], ghi ? c[nz - 1] : T(0));
}

template <typename T, bool FACES, bool KFULL, bool SPONGE>
void volume_steps(const VolumeArgs<T>& a) {
  const int64_t nx = a.nx, ny = a.ny, nz = a.nz, S = ny * nz;
  const CellPlan<T> cplan(a.cells, nx);
  const bool stats = a.cells.p_max || a.cells.p_sq || a.cells.arrival;
  const std::vector<T> zero(S, T(0));
  T* buf[2] = {a.p, a.pp};  // step L lives in buf[L % 2] (step 0 = P(t) in buf[0])
  auto make_worker = [&](int) {
    return [&](int, int64_t L, int64_t i) {
      const T* p = buf[(L - 1) & 1];  // step L - 1
      T* pp = buf[L & 1];             // step L - 2, overwritten by step L
      const T* P0 = p + i * S;
      // ghost planes: the plane itself on a closed side with unit faces, else zeros
      const T* PM = i > 0 ? P0 - S : (!FACES && a.closed[0] ? P0 : zero.data());
      const T* PP = i + 1 < nx ? P0 + S : (!FACES && a.closed[1] ? P0 : zero.data());
      T* out = pp + i * S;
      VolRow<T> r{};
      for (int64_t j = 0; j < ny; ++j) {
        const int64_t off = j * nz;
        r.c = P0 + off;
        r.xm = PM + off;
        r.xp = PP + off;
        r.ym = j > 0 ? r.c - nz : (!FACES && a.closed[2] ? r.c : zero.data());
        r.yp = j + 1 < ny ? r.c + nz : (!FACES && a.closed[3] ? r.c : zero.data());
        r.o = out + off;
        if constexpr (FACES) {
          r.bxl = a.bx + i * S + off;
          r.bxh = r.bxl + S;
          r.byl = a.by + i * (ny + 1) * nz + off;
          r.byh = r.byl + nz;
          r.bz = a.bz + (i * ny + j) * (nz + 1);
        }
        if constexpr (KFULL) r.kr = a.K + i * S + off;
        if constexpr (SPONGE) r.sr = a.sponge + i * S + off;
        volume_row<T, FACES, KFULL, SPONGE>(r, nz, a.k, a.closed[4], a.closed[5]);
      }
      if (a.keep) {
        const T* kp = a.keep + i * S;
#pragma GCC ivdep
        for (int64_t j = 0; j < S; ++j) out[j] = kp[j] * out[j];
      }
      if (cplan.busy[i]) leapfrog_cells(a.cells, cplan, i, L - 1, pp);
      if (stats) row_stats(a.cells, i, L - 1, out);
    };
  };
  // an odd number of steps leaves the latest field in the P(t-1) buffer: swap the contents
  auto finish = [&](int t, int nt) {
    if (a.n_steps % 2 == 0) return;
    const int64_t r0 = nx * t / nt, r1 = nx * (t + 1) / nt;
    std::swap_ranges(a.p + r0 * S, a.p + r1 * S, a.pp + r0 * S);
  };
  pipeline(nx, S, a.n_steps, a.n_threads, std::max(1, a.levels), make_worker, finish);
}

template <typename T>
void volume(const VolumeArgs<T>& a) {
  const bool faces = a.bx != nullptr, kfull = a.K != nullptr, sponge = a.sponge != nullptr;
  const int which = (faces ? 4 : 0) + (kfull ? 2 : 0) + (sponge ? 1 : 0);
  switch (which) {
    case 0: return volume_steps<T, false, false, false>(a);
    case 1: return volume_steps<T, false, false, true>(a);
    case 2: return volume_steps<T, false, true, false>(a);
    case 3: return volume_steps<T, false, true, true>(a);
    case 4: return volume_steps<T, true, false, false>(a);
    case 5: return volume_steps<T, true, false, true>(a);
    case 6: return volume_steps<T, true, true, false>(a);
    default: return volume_steps<T, true, true, true>(a);
  }
}

}  // namespace dl
