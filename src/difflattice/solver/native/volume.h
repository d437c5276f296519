// the 3-D leapfrog over a block of steps: the 7-point flux stencil of lattice.operators on a volume,
// x planes as the pipeline's rows (temporal blocking, threads), sources and sensors per plane
// (part of the native kernels: included by volume.cc)
#pragma once

#include <algorithm>
#include <atomic>
#include <thread>
#include <cstdint>
#include <vector>

#include "cells.h"
#include "threads.h"

namespace dl {

// the step of the JAX 3-D loop (solver.stepper, standard stencil):
//   P(n+1) = 2 P(n) - P(n-1) + K L(P(n))              (no sponge)
//   P(n+1) = (2 P(n) - (1 - s) P(n-1) + K L(P(n))) / (1 + s)   (sponge s)
// then P(n+1) *= keep (soft cells), then the sources, then the records. L sums the axes in order
// x, y, z; an axis term is (q_hi + q_lo) - 2 q on unit faces (here: the six neighbours summed, minus
// 6 q; a closed window side: the ghost is the cell itself, a zero flux; an open or soft side: the
// ghost is 0), b_hi (q_hi - q) - b_lo (q - q_lo) with face conductances (every outer face's conductance carries its side, the ghosts are 0)
template <typename T>
struct VolumeArgs {
  int64_t nx, ny, nz, n_steps;
  int n_threads, levels;
  int64_t band = 0;  // rows of a plane's bands (0: whole planes; band_pipeline)
  bool iso = false;  // the isotropic 19-point stencil (uniform faces only: no bx, by, bz)
  const void* layers = nullptr;  // VolumeLayers<T> (PML layers; standard stencil, no sponge) or nullptr
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

// the leapfrog's new value of cell j from its operand q and Laplacian lap: K (scalar k or the row
// kr), the sponge's damping (row sr); o[j] holds P(n-1) on entry (every 3-D row kernel ends so)
template <typename T, bool KFULL, bool SPONGE>
__attribute__((always_inline)) inline void leapfrog_update(T* __restrict o, const T* __restrict kr,
                                                           const T* __restrict sr, int64_t j, T q, T k, T lap) {
  T kk = k;
  if constexpr (KFULL) kk = kr[j];
  const T d = kk * lap;
  if constexpr (SPONGE) {
    const T s = sr[j];
    o[j] = ((T(2) * q - (T(1) - s) * o[j]) + d) / (T(1) + s);
  } else {
    o[j] = (T(2) * q - o[j]) + d;
  }
}

template <typename T, bool FACES, bool KFULL, bool SPONGE>
inline void volume_row(const VolRow<T>& r, int64_t nz, T k, bool zlo, bool zhi) {
  const T* __restrict c = r.c;
  const T* __restrict xm = r.xm;
  const T* __restrict xp = r.xp;
  const T* __restrict ym = r.ym;
  const T* __restrict yp = r.yp;
  T* __restrict o = r.o;
  const T centre = T(2) - T(6) * k;  // unit faces, scalar K: 2 P(n) - 6 K P(n)
  auto cell = [&](int64_t j, T zm, T zp) __attribute__((always_inline)) {
    const T q = c[j];
    T lap;
    if constexpr (FACES) {
      const T tx = r.bxh[j] * (xp[j] - q) - r.bxl[j] * (q - xm[j]);
      const T ty = r.byh[j] * (yp[j] - q) - r.byl[j] * (q - ym[j]);
      const T tz = r.bz[j + 1] * (zp - q) - r.bz[j] * (q - zm);
      lap = (tx + ty) + tz;
    } else {
      // unit faces: the neighbours summed first (numba's and the 2-D kernel's order; 7 operations a
      // cell against 12 in the JAX loop's order, which bounded this loop in cache: equal to rounding)
      const T sum = ((((xp[j] + xm[j]) + yp[j]) + ym[j]) + zp) + zm;
      if constexpr (!KFULL && !SPONGE) {
        o[j] = (centre * q - o[j]) + k * sum;
        return;
      }
      lap = sum - T(6) * q;
    }
    leapfrog_update<T, KFULL, SPONGE>(o, r.kr, r.sr, j, q, k, lap);
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

// rows [ja, jb) of a plane (0 < ja, jb < ny: their y neighbours are rows of the plane) with unit
// faces as one flat loop over their cells: the z neighbours are the cells at -+1, which for a row's
// first and last cells are the neighbouring rows' cells, so those two cells a row are computed
// again afterwards from P(n-1) saved before the loop, with their ghosts, in the same arithmetic
// (bit-identical to volume_row). The flat loop has no per-row prologue or scalar remainder (with
// 512-bit vectors a 16-cell loop over a row's 254 inner cells ends in an 8-wide and 6 scalar
// iterations, plus 2 scalar edge cells): 256^3, 8 levels, callgrind on an AVX2 build, 2.31 -> 1.85
// instructions a cell update; through JAX (64-byte aligned fields) ~12 % less CPU time, one thread.
// c: plane i of P(n); xm, xp: planes i -+ 1 (or ghosts); o, kr, sr: the plane's P(n-1) -> P(n+1), K,
// sponge; everything indexed by j nz + k
template <typename T, bool KFULL, bool SPONGE>
inline void volume_rows_flat(const T* __restrict c, const T* __restrict xm, const T* __restrict xp,
                             T* __restrict o, const T* __restrict kr, const T* __restrict sr, int64_t nz,
                             int64_t ja, int64_t jb, T k, bool zlo, bool zhi) {
  constexpr int64_t R = 8;  // rows a chunk: its edge cells' P(n-1) saved, fixed while in L1
  T lo_old[R], hi_old[R];
  const T centre = T(2) - T(6) * k;
  for (int64_t r0 = ja; r0 < jb; r0 += R) {
    const int64_t r1 = std::min(jb, r0 + R), f0 = r0 * nz, f1 = r1 * nz;
    for (int64_t j = r0; j < r1; ++j) {
      lo_old[j - r0] = o[j * nz];
      hi_old[j - r0] = o[j * nz + nz - 1];
    }
#pragma GCC ivdep
    for (int64_t f = f0; f < f1; ++f) {
      const T q = c[f];
      const T sum = ((((xp[f] + xm[f]) + c[f + nz]) + c[f - nz]) + c[f + 1]) + c[f - 1];
      if constexpr (!KFULL && !SPONGE) {
        o[f] = (centre * q - o[f]) + k * sum;
      } else {
        leapfrog_update<T, KFULL, SPONGE>(o, kr, sr, f, q, k, sum - T(6) * q);
      }
    }
    // the edge cells: as volume_row's cell(0, ...) and cell(nz - 1, ...), from the saved P(n-1)
    auto edge = [&](int64_t f, T zm, T zp, T old) {
      const T q = c[f];
      const T sum = ((((xp[f] + xm[f]) + c[f + nz]) + c[f - nz]) + zp) + zm;
      o[f] = old;
      if constexpr (!KFULL && !SPONGE) {
        o[f] = (centre * q - o[f]) + k * sum;
      } else {
        leapfrog_update<T, KFULL, SPONGE>(o, kr, sr, f, q, k, sum - T(6) * q);
      }
    };
    for (int64_t j = r0; j < r1; ++j) {
      const int64_t f = j * nz, e = f + nz - 1;
      edge(f, zlo ? c[f] : T(0), c[f + 1], lo_old[j - r0]);
      edge(e, c[e - 1], zhi ? c[e] : T(0), hi_old[j - r0]);
    }
  }
}

// PML layers (lattice.pml, stepper._layer_step): the split-field form on the layer's boxes, whose
// cells' new pressure replaces the leapfrog's. Per box (x0 x1 y0 y1 z0 z1, cells [lo, hi) per axis)
// the parts px, py, pz (box shape) and the face fluxes wx, wy, wz (one more face along their axis),
// packed box after box (kernels._pack_layers' order); the factors a, b per axis as profiles along it
template <typename T>
struct VolumeLayers {
  int64_t n_boxes = 0;
  const int32_t* boxes = nullptr;      // (n_boxes, 6)
  std::vector<int64_t> part_at, flux_at;  // offsets of each box's fields in parts, fluxes
  T* parts = nullptr;
  T* fluxes = nullptr;
  const T* a_cell[3] = {nullptr, nullptr, nullptr};  // (n_axis,) profiles
  const T* b_cell[3] = {nullptr, nullptr, nullptr};
  const T* a_face[3] = {nullptr, nullptr, nullptr};  // (n_axis + 1,)
  const T* b_face[3] = {nullptr, nullptr, nullptr};
};

// plane i, rows [j0, j1) of step L's layer cells: q = P(n) (planes qm, q0, qp: i - 1, i, i + 1, zero
// beyond the window), out = the new plane (the leapfrog's values, replaced in the boxes)
template <typename T, bool FACES, bool KFULL>
void volume_layers(const VolumeArgs<T>& a, const VolumeLayers<T>& la, int64_t i, int64_t j0, int64_t j1,
                   const T* qm, const T* q0, const T* qp, T* out, const T* zero) {
  const int64_t nx = a.nx, ny = a.ny, nz = a.nz, S = ny * nz;
  // face conductances: the arrays, or unit faces closed on rigid window sides
  auto cx = [&](int64_t f, int64_t j, int64_t k) -> T {
    if constexpr (FACES) return a.bx[(f * ny + j) * nz + k];
    return ((f == 0 && a.closed[0]) || (f == nx && a.closed[1])) ? T(0) : T(1);
  };
  auto cy = [&](int64_t f, int64_t j, int64_t k) -> T {
    if constexpr (FACES) return a.by[(i * (ny + 1) + f) * nz + k];
    return ((f == 0 && a.closed[2]) || (f == ny && a.closed[3])) ? T(0) : T(1);
  };
  auto cz = [&](int64_t f, int64_t j, int64_t k) -> T {
    if constexpr (FACES) return a.bz[(i * ny + j) * (nz + 1) + f];
    return ((f == 0 && a.closed[4]) || (f == nz && a.closed[5])) ? T(0) : T(1);
  };
  for (int64_t bi = 0; bi < la.n_boxes; ++bi) {
    const int32_t* bx = la.boxes + 6 * bi;
    const int64_t x0 = bx[0], x1 = bx[1], y0 = bx[2], y1 = bx[3], z0 = bx[4], z1 = bx[5];
    if (i < x0 || i >= x1) continue;
    const int64_t r0 = std::max(j0, y0), r1 = std::min(j1, y1);
    if (r0 >= r1) continue;
    const int64_t X = x1 - x0, Y = y1 - y0, Z = z1 - z0, n = X * Y * Z;
    T* px = la.parts + la.part_at[bi];
    T* py = px + n;
    T* pz = py + n;
    T* wx = la.fluxes + la.flux_at[bi];  // (X + 1, Y, Z)
    T* wy = wx + (X + 1) * Y * Z;        // (X, Y + 1, Z)
    T* wz = wy + X * (Y + 1) * Z;        // (X, Y, Z + 1)
    const int64_t u = i - x0;
    for (int64_t j = r0; j < r1; ++j) {
      const int64_t v = j - y0;
      const T* qr = q0 + j * nz;
      const T* qxm = qm + j * nz;
      const T* qxp = qp + j * nz;
      const T* qym = j > 0 ? qr - nz : zero;  // zero beyond the window
      const T* qyp = j + 1 < ny ? qr + nz : zero;
      // x faces: the box's first face on its first plane (face i + 1: in the fused loop below)
      for (int64_t f = i; f == x0; ++f) {
        const T* lo = f == i ? qxm : qr;
        const T* hi = f == i ? qr : qxp;
        const T af = la.a_face[0][f], bf = la.b_face[0][f];
        T* w = wx + ((f - x0) * Y + v) * Z - z0;
        for (int64_t k = z0; k < z1; ++k) w[k] = af * w[k] + bf * (cx(f, j, k) * (hi[k] - lo[k]));
      }
      // y faces: the box's first face on its first row (face j + 1: in the fused loop below)
      for (int64_t f = j; f == y0; ++f) {
        const T* lo = f == j ? qym : qr;
        const T* hi = f == j ? qr : qyp;
        const T af = la.a_face[1][f], bf = la.b_face[1][f];
        T* w = wy + (u * (Y + 1) + (f - y0)) * Z - z0;
        for (int64_t k = z0; k < z1; ++k)
          w[k] = af * w[k] + bf * (cy(f, j, k) * (hi[k] - lo[k]));
      }
      // z faces of the row: z0 .. z1
      T* wzr = wz + (u * Y + v) * (Z + 1) - z0;
      auto zface = [&](int64_t f, T lo, T hi) { wzr[f] = la.a_face[2][f] * wzr[f] + la.b_face[2][f] * (cz(f, j, f) * (hi - lo)); };
      const int64_t f0 = std::max<int64_t>(z0, 1), f1 = std::min<int64_t>(z1, nz - 1);
      if (z0 == 0) zface(0, T(0), nz > 0 ? qr[0] : T(0));
      for (int64_t f = f0; f <= f1; ++f) zface(f, qr[f - 1], qr[f]);
      if (z1 == nz) zface(nz, qr[nz - 1], T(0));
      // the parts, then P = px + py + pz
      const T* __restrict wxl = wx + (u * Y + v) * Z - z0;  // faces i and j (new: updated before)
      const T* __restrict wyl = wy + (u * (Y + 1) + v) * Z - z0;
      const int64_t c0 = ((u * Y) + v) * Z - z0;
      const T axc = la.a_cell[0][i], bxc = la.b_cell[0][i];
      const T ayc = la.a_cell[1][j], byc = la.b_cell[1][j];
      // (local restrict pointers and values: the loop vectorises)
      T* __restrict o = out + j * nz;
      T* __restrict sxp = px + c0;
      T* __restrict syp = py + c0;
      T* __restrict szp = pz + c0;
      const T* __restrict kr = KFULL ? a.K + i * S + j * nz : nullptr;
      const T* __restrict keep = a.keep ? a.keep + i * S + j * nz : nullptr;
      const T* __restrict azc = la.a_cell[2];
      const T* __restrict bzc = la.b_cell[2];
      const T ks = a.k;
      // faces i + 1 and j + 1 of the row, updated in the loop of the parts (one loop a row: the
      // z-slab boxes' rows are short, and a loop's set-up cost was most of their time)
      T* __restrict wxn = wx + ((i + 1 - x0) * Y + v) * Z - z0;
      T* __restrict wyn = wy + (u * (Y + 1) + (j + 1 - y0)) * Z - z0;
      const T* __restrict qh = qxp;
      const T* __restrict qyh = qyp;
      const T* __restrict qc = qr;
      const T afx = la.a_face[0][i + 1], bfx = la.b_face[0][i + 1];
      const T afy = la.a_face[1][j + 1], bfy = la.b_face[1][j + 1];
      const T* __restrict cxr = nullptr;
      const T* __restrict cyr = nullptr;
      T cxs = T(1), cys = T(1);
      if constexpr (FACES) {
        cxr = a.bx + ((i + 1) * ny + j) * nz;
        cyr = a.by + (i * (ny + 1) + j + 1) * nz;
      } else {
        cxs = cx(i + 1, j, 0);
        cys = cy(j + 1, j, 0);
      }
      auto part = [&](int64_t k, T kp) __attribute__((always_inline)) {
        T gx = qh[k] - qc[k], gy = qyh[k] - qc[k];
        if constexpr (FACES) {
          gx = cxr[k] * gx;
          gy = cyr[k] * gy;
        } else {
          gx = cxs * gx;
          gy = cys * gy;
        }
        const T wxk = afx * wxn[k] + bfx * gx, wyk = afy * wyn[k] + bfy * gy;
        wxn[k] = wxk;
        wyn[k] = wyk;
        T kk = ks;
        if constexpr (KFULL) kk = kr[k];
        const T sx = kp * (axc * sxp[k] + bxc * (kk * (wxk - wxl[k])));
        const T sy = kp * (ayc * syp[k] + byc * (kk * (wyk - wyl[k])));
        const T sz = kp * (azc[k] * szp[k] + bzc[k] * (kk * (wzr[k + 1] - wzr[k])));
        sxp[k] = sx;
        syp[k] = sy;
        szp[k] = sz;
        o[k] = (sx + sy) + sz;
      };
      if (keep) {
#pragma GCC ivdep
        for (int64_t k = z0; k < z1; ++k) part(k, keep[k]);
      } else {
        // without soft cells: no factor (kp * s with kp = 1 is exact: the same values)
#pragma GCC ivdep
        for (int64_t k = z0; k < z1; ++k) part(k, T(1));
      }
    }
  }
}

// the isotropic 19-point stencil on uniform faces (lattice.operators._isotropic_uniform_3d):
//   L(q) = (sum of the 6 axis neighbours) / 3 + (sum of the 12 face-diagonal neighbours) / 6 - 4 q
// a neighbour beyond a rigid side is the boundary cell itself (the even mirror; across two sides
// only if both are rigid), beyond any other side 0: the row pointers carry the x and y ghosts
// (`VolRowIso`), `zlo`/`zhi` the z ones
template <typename T>
struct VolRowIso {
  const T *c, *xm, *xp, *ym, *yp;       // rows (i, j), (i -+ 1, j), (i, j -+ 1)
  const T *xmym, *xmyp, *xpym, *xpyp;  // the diagonal rows (i -+ 1, j -+ 1)
  const T *kr, *sr;
  T* o;
};

template <typename T, bool KFULL, bool SPONGE>
inline void volume_row_iso(const VolRowIso<T>& r, int64_t nz, T k, bool zlo, bool zhi) {
  const T* __restrict c = r.c;
  const T* __restrict xm = r.xm;
  const T* __restrict xp = r.xp;
  const T* __restrict ym = r.ym;
  const T* __restrict yp = r.yp;
  const T* __restrict mm = r.xmym;
  const T* __restrict mp = r.xmyp;
  const T* __restrict pm = r.xpym;
  const T* __restrict pp = r.xpyp;
  T* __restrict o = r.o;
  const T third = T(1) / T(3), sixth = T(1) / T(6);
  // (z neighbours of c, xm, xp, ym, yp: below, above)
  auto cell = [&](int64_t j, T cz0, T cz1, T xmz0, T xmz1, T xpz0, T xpz1, T ymz0, T ymz1, T ypz0, T ypz1)
      __attribute__((always_inline)) {
    const T q = c[j];
    const T axis = ((((xp[j] + xm[j]) + yp[j]) + ym[j]) + cz1) + cz0;
    // _FACE_DIAGONALS' order: (-1,-1,0) (-1,0,-1) (-1,0,1) (-1,1,0) (0,-1,-1) (0,-1,1) (0,1,-1) (0,1,1)
    // (1,-1,0) (1,0,-1) (1,0,1) (1,1,0)
    const T diag = (((((((((((mm[j] + xmz0) + xmz1) + mp[j]) + ymz0) + ymz1) + ypz0) + ypz1) + pm[j]) + xpz0) + xpz1) +
                   pp[j]);
    const T lap = (axis * third + diag * sixth) - T(4) * q;
    leapfrog_update<T, KFULL, SPONGE>(o, r.kr, r.sr, j, q, k, lap);
  };
  auto lo = [&](const T* row) { return zlo ? row[0] : T(0); };            // the ghost below k = 0
  auto hi = [&](const T* row) { return zhi ? row[nz - 1] : T(0); };       // above k = nz - 1
  if (nz == 1) {
    cell(0, lo(c), hi(c), lo(xm), hi(xm), lo(xp), hi(xp), lo(ym), hi(ym), lo(yp), hi(yp));
    return;
  }
  cell(0, lo(c), c[1], lo(xm), xm[1], lo(xp), xp[1], lo(ym), ym[1], lo(yp), yp[1]);
#pragma GCC ivdep
  for (int64_t j = 1; j < nz - 1; ++j)
    cell(j, c[j - 1], c[j + 1], xm[j - 1], xm[j + 1], xp[j - 1], xp[j + 1], ym[j - 1], ym[j + 1], yp[j - 1], yp[j + 1]);
  const int64_t e = nz - 1;
  cell(e, c[e - 1], hi(c), xm[e - 1], hi(xm), xp[e - 1], hi(xp), ym[e - 1], hi(ym), yp[e - 1], hi(yp));
}

// the blocks of steps: ceil(n_steps / (threads levels)) blocks, the steps spread evenly over them
// (100 steps on 2 threads x 8 levels: 7 blocks of 14-15 steps, not 6 of 16 and one of 4, whose
// sweep would cost the memory traffic of a whole block for a quarter of its steps)
struct Blocks {
  int64_t n_steps, n_blocks, nt;
  Blocks(int64_t n_steps_, int nt_, int levels)
      : n_steps(n_steps_), n_blocks((n_steps_ + int64_t(nt_) * levels - 1) / (int64_t(nt_) * levels)), nt(nt_) {}
  int64_t start(int64_t k) const { return n_blocks ? n_steps * k / n_blocks : 0; }  // steps before block k
  int64_t size(int64_t k) const { return start(k + 1) - start(k); }
  // thread t's steps in block k: [first, first + mine) (1-based), the lower threads take the extra
  void of(int64_t k, int64_t t, int64_t* first, int64_t* mine) const {
    const int64_t n = size(k), base = n / nt, extra = n % nt;
    *first = start(k) + 1 + t * base + std::min<int64_t>(t, extra);
    *mine = base + (t < extra ? 1 : 0);
  }
};

// wait until `progress` reaches `need` (spinning, then yielding to an oversubscribed machine)
inline void wait_for(const std::atomic<int64_t>& progress, int64_t need, int64_t* seen) {
  int spins = 0;
  while (*seen < need) {
    *seen = progress.load(std::memory_order_acquire);
    if (*seen >= need) break;
    if (++spins < 4000) DL_PAUSE();
    else std::this_thread::yield();
  }
}

// The pipeline of whole x planes: in block k, thread t advances its `mine` steps in one sweep over
// the planes (step first + l at plane m - l at sweep position m), its first step waiting until the
// owner of the step before it (thread t - 1, or for thread 0 the last thread of block k - 1) has
// finished the plane after the one it computes. No barrier between blocks: thread 0 starts block
// k + 1 while the last thread is still in block k, so neither waits for the other's pipeline fill
// or drain at each block (each thread's progress counts planes over all blocks: k nx + planes).
// Every hazard is between a step and the two after it (the fields alternate), and each waits for
// its predecessor through the next plane, so no thread overtakes data still needed.
template <typename MakeWorker, typename Finish>
void plane_pipeline(int64_t nx, int64_t ny, int64_t n_steps, int n_threads, int levels, MakeWorker&& make_worker,
                    Finish&& finish) {
  const int nt = std::max(1, n_threads);
  const Blocks blocks(n_steps, nt, std::max(1, levels));
  std::vector<Progress> progress(nt);
  SpinBarrier barrier(nt);
  parallel(nt, [&](int t) {
    auto row = make_worker(t);
    int64_t seen = 0;
    int prev_owner = -1;
    for (int64_t k = 0; k < blocks.n_blocks; ++k) {
      int64_t first, mine;
      blocks.of(k, t, &first, &mine);
      if (mine == 0) continue;  // (fewer steps than threads in this block)
      // the owner of step first - 1 and the progress it must reach (0: none, the call's start)
      int owner = -1;
      int64_t base = 0;
      if (t > 0) {
        owner = t - 1;  // (a lower thread never has fewer steps)
        base = k * nx;
      } else if (k > 0) {
        owner = int(std::min<int64_t>(nt, blocks.size(k - 1)) - 1);
        base = (k - 1) * nx;
      }
      if (owner != prev_owner) seen = 0;
      prev_owner = owner;
      for (int64_t m = 0; m < nx + mine - 1; ++m) {
        for (int64_t l = 0; l < mine; ++l) {
          const int64_t i = m - l;
          if (i < 0 || i >= nx) continue;
          if (l == 0 && owner >= 0) wait_for(progress[owner].rows, base + std::min<int64_t>(i + 2, nx), &seen);
          row(first + l, i, int64_t(0), ny);
          if (l == mine - 1) progress[t].rows.store(k * nx + i + 1, std::memory_order_release);
        }
      }
    }
    barrier.wait();
    finish(t, nt);
  });
}

// The pipeline over the x planes with each plane cut into bands of `band` rows along y, skewed by
// one row per step: in a block of steps, band b of the block's g-th step (0-based) is the rows
// [b band - g, (b + 1) band - g), so a band's steps read only rows of the bands before it (done,
// and not yet overwritten: the two fields alternate) or of itself; a barrier between bands. A band
// of the planes in flight (about levels + 3 of each field) fits in L2 where a whole plane does not
// (but: 16 bands-of-planes a few rows apart, all 64 KB-periodic, share the same L2 sets). Whole
// planes (band 0): plane_pipeline. `make_worker(t)` returns row(L, i, j0, j1): rows [j0, j1) of
// plane i of step L.
template <typename MakeWorker, typename Finish>
void band_pipeline(int64_t nx, int64_t ny, int64_t band, int64_t n_steps, int n_threads, int levels,
                   MakeWorker&& make_worker, Finish&& finish) {
  if (band <= 0) return plane_pipeline(nx, ny, n_steps, n_threads, levels, make_worker, finish);
  const int nt = std::max(1, n_threads);
  const Blocks blocks(n_steps, nt, std::max(1, levels));
  std::vector<Progress> progress(nt);
  SpinBarrier barrier(nt);
  parallel(nt, [&](int t) {
    auto row = make_worker(t);
    for (int64_t k = 0; k < blocks.n_blocks; ++k) {
      const int64_t s0 = blocks.start(k), n_block = blocks.size(k);
      int64_t first, mine;
      blocks.of(k, t, &first, &mine);
      const bool whole = band >= ny + n_block;
      const int64_t n_bands = whole ? 1 : (ny + n_block - 1 + band - 1) / band;
      for (int64_t b = 0; b < n_bands; ++b) {
        progress[t].rows.store(0, std::memory_order_relaxed);
        barrier.wait();
        if (mine > 0) {
          const bool wait_prev = t > 0 && first - 1 > s0;  // step first - 1 is another thread's
          int64_t seen = 0;
          for (int64_t m = 0; m < nx + mine - 1; ++m) {
            for (int64_t l = 0; l < mine; ++l) {
              const int64_t i = m - l;
              if (i < 0 || i >= nx) continue;
              if (l == 0 && wait_prev) wait_for(progress[t - 1].rows, std::min<int64_t>(i + 2, nx), &seen);
              const int64_t g = first + l - s0 - 1;
              const int64_t j0 = whole ? 0 : std::clamp<int64_t>(b * band - g, 0, ny);
              const int64_t j1 = whole ? ny : std::clamp<int64_t>((b + 1) * band - g, 0, ny);
              if (j0 < j1) row(first + l, i, j0, j1);
              if (l == mine - 1) progress[t].rows.store(i + 1, std::memory_order_release);
            }
          }
        } else {
          progress[t].rows.store(nx, std::memory_order_release);
        }
        barrier.wait();
      }
    }
    finish(t, nt);
  });
}

template <typename T, bool FACES, bool KFULL, bool SPONGE, bool ISO = false>
void volume_steps(const VolumeArgs<T>& a) {
  const int64_t nx = a.nx, ny = a.ny, nz = a.nz, S = ny * nz;
  const CellPlan<T> cplan(a.cells, nx);
  const bool stats = a.cells.p_max || a.cells.p_sq || a.cells.arrival;
  const std::vector<T> zero(S, T(0));
  T* buf[2] = {a.p, a.pp};  // step L lives in buf[L % 2] (step 0 = P(t) in buf[0])
  // rows (i, j) that a PML box covers whole (all of z): the layer writes them, the leapfrog skips them
  std::vector<char> covered;
  if (a.layers) {
    const auto& la = *static_cast<const VolumeLayers<T>*>(a.layers);
    covered.assign(nx * ny, 0);
    for (int64_t b = 0; b < la.n_boxes; ++b) {
      const int32_t* x = la.boxes + 6 * b;
      if (x[4] != 0 || x[5] != nz) continue;
      for (int64_t i = x[0]; i < x[1]; ++i)
        for (int64_t j = x[2]; j < x[3]; ++j) covered[i * ny + j] = 1;
    }
  }
  const char* skip = covered.empty() ? nullptr : covered.data();
  auto make_worker = [&](int) {
    return [&](int64_t L, int64_t i, int64_t j0, int64_t j1) {
      const T* p = buf[(L - 1) & 1];  // step L - 1
      T* pp = buf[L & 1];             // step L - 2, overwritten by step L
      const T* P0 = p + i * S;
      // ghost planes: the plane itself on a closed side with unit faces, else zeros
      const T* PM = i > 0 ? P0 - S : (!FACES && a.closed[0] ? P0 : zero.data());
      const T* PP = i + 1 < nx ? P0 + S : (!FACES && a.closed[1] ? P0 : zero.data());
      T* out = pp + i * S;
      if constexpr (ISO) {  // uniform faces only (FACES false): ghost rows as the ghost planes
        auto row_of = [&](const T* plane, int64_t jj, int64_t j) {
          if (jj < 0) return a.closed[2] ? plane + j * nz : zero.data();
          if (jj >= ny) return a.closed[3] ? plane + j * nz : zero.data();
          return plane + jj * nz;
        };
        VolRowIso<T> r{};
        for (int64_t j = j0; j < j1; ++j) {
          const int64_t off = j * nz;
          r.c = P0 + off;
          r.xm = PM + off;
          r.xp = PP + off;
          r.ym = row_of(P0, j - 1, j);
          r.yp = row_of(P0, j + 1, j);
          r.xmym = row_of(PM, j - 1, j);
          r.xmyp = row_of(PM, j + 1, j);
          r.xpym = row_of(PP, j - 1, j);
          r.xpyp = row_of(PP, j + 1, j);
          r.o = out + off;
          if constexpr (KFULL) r.kr = a.K + i * S + off;
          if constexpr (SPONGE) r.sr = a.sponge + i * S + off;
          volume_row_iso<T, KFULL, SPONGE>(r, nz, a.k, a.closed[4], a.closed[5]);
        }
      }
      // unit faces without layers: the rows between the first and the last as one flat loop
      int64_t fa = j1, fb = j1;  // the flat rows [fa, fb)
      if constexpr (!ISO && !FACES) {
        if (!skip && nz >= 2) {
          fa = std::max<int64_t>(j0, 1);
          fb = std::max(fa, std::min<int64_t>(j1, ny - 1));
          if (fa < fb)
            volume_rows_flat<T, KFULL, SPONGE>(P0, PM, PP, out, KFULL ? a.K + i * S : nullptr,
                                               SPONGE ? a.sponge + i * S : nullptr, nz, fa, fb, a.k, a.closed[4],
                                               a.closed[5]);
        }
      }
      VolRow<T> r{};
      for (int64_t j = ISO ? j1 : j0; j < j1; ++j) {
        if (j == fa) j = fb;  // done flat
        if (j >= j1) break;
        if (skip && skip[i * ny + j]) continue;  // a layer row: the boxes write it
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
      const int64_t c0 = j0 * nz, c1 = j1 * nz;
      if (a.keep) {
        const T* kp = a.keep + i * S;
#pragma GCC ivdep
        for (int64_t j = c0; j < c1; ++j) out[j] = kp[j] * out[j];
      }
      if constexpr (!ISO && !SPONGE) {
        if (a.layers) {  // zero ghost planes for the layers' gradients (closed faces carry b = 0)
          const T* qm = i > 0 ? P0 - S : zero.data();
          const T* qp = i + 1 < nx ? P0 + S : zero.data();
          volume_layers<T, FACES, KFULL>(a, *static_cast<const VolumeLayers<T>*>(a.layers), i, j0, j1, qm, P0, qp,
                                         out, zero.data());
        }
      }
      if (cplan.busy[i]) leapfrog_cells(a.cells, cplan, i, L - 1, pp, c0, c1);
      if (stats) row_stats(a.cells, i, L - 1, out, c0, c1);
    };
  };
  // an odd number of steps leaves the latest field in the P(t-1) buffer: swap the contents
  auto finish = [&](int t, int nt) {
    if (a.n_steps % 2 == 0) return;
    const int64_t r0 = nx * t / nt, r1 = nx * (t + 1) / nt;
    std::swap_ranges(a.p + r0 * S, a.p + r1 * S, a.pp + r0 * S);
  };
  band_pipeline(nx, ny, a.band, a.n_steps, a.n_threads, std::max(1, a.levels), make_worker, finish);
}

template <typename T>
void volume(const VolumeArgs<T>& a) {
  const bool faces = a.bx != nullptr, kfull = a.K != nullptr, sponge = a.sponge != nullptr;
  if (a.iso) {  // uniform faces (the caller checks)
    const int w = (kfull ? 2 : 0) + (sponge ? 1 : 0);
    if (w == 0) return volume_steps<T, false, false, false, true>(a);
    if (w == 1) return volume_steps<T, false, false, true, true>(a);
    if (w == 2) return volume_steps<T, false, true, false, true>(a);
    return volume_steps<T, false, true, true, true>(a);
  }
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
