// the leapfrog's row kernels (standard and isotropic stencils) and their per-row plans
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
// the leapfrog: one row of the flux stencil
//
// L(q)_ij = tx + ty; per axis (operators.stencil) c_hi (hi - q) - c_lo (q - lo), which is
// hi + lo - 2 q where both faces of the cell have unit conductance. Combine forms:
//   kFwd:  out = (2 p - pp) + K L(q)            (the plain leapfrog; q rows are p rows)
//   kD:    out = K L(q)                          (combined later with sponge / keep)
//   kAdj:  out = (2 a + L(u)) - h,  u = K a      (the adjoint step; h = -g0, q rows are u rows)

enum Combine : int { kFwd = 0, kD = 1, kAdj = 2 };
// a row's face conductances along one axis; kMetric: the rz ring metric alone (y only), whose two
// factors sum to 2 inside the row (A_(j+1) + A_j = 2 V_j): m_hi = 1 + g, m_lo = 1 - g with
// g = 1 / (2 j + 1), so the update keeps the unit stencil's form plus one multiply-add and one
// row of per-column factors: qn m_hi + qs m_lo - 2 q = (qn + qs) + g (qn - qs) - 2 q
enum Faces : int { kUnit = 0, kReg = 1, kVec = 2, kMetric = 3 };

template <typename T>
struct RowIO {
  const T *qm, *q0, *qp;  // q rows i - 1, i, i + 1 (zero rows beyond the window)
  const T* p0;            // p row i (kD, kAdj)
  const T* pp0;           // pp row i (read before `out` is written at the same index)
  T* out;
};

template <typename T>
struct RowCtx {  // a row's coefficients (planned once per call)
  T k, c0;        // scalar K and 2 - 4 K
  const T* krow;  // K row (vector K)
  T bxlo, bxhi;   // kReg: x faces of the row
  const T *bxlo_r, *bxhi_r;
  T by;                    // kReg: both y faces of every cell of the row
  const T *cyl, *cyh;      // kVec: the low and high y face of each cell (ny each)
  const T* cyg;            // kMetric: (cyh - cyl) / 2 per cell (ny; the ring form's g)
  T by_first_lo, by_first_hi, by_last_lo, by_last_hi;  // y faces of the cells j = 0 and ny - 1
  const T *rl, *rh;        // isotropic stencil: weights of the filter across the x faces (ny each)
  T am, ap;                // isotropic stencil: 1 where the row has a low / high neighbour, else 0
  const T *bym, *by0, *byp;  // isotropic stencil, face arrays: y faces of rows i - 1, i, i + 1
  const T* inva;             // isotropic stencil, face arrays: 1 / (ring area) per column
};

// an edge cell (its outer neighbour zero), in the reference form
template <typename T, int BX, bool KREG, int CMB>
static inline T edge_cell(const RowCtx<T>& c, const RowIO<T>& io, int64_t j, T s, T n, T by_lo, T by_hi) {
  const T q = io.q0[j], e = io.qp[j], w = io.qm[j];
  T tx;
  if constexpr (BX == kUnit) tx = (e + w) - T(2) * q;
  else if constexpr (BX == kReg) tx = c.bxhi * (e - q) - c.bxlo * (q - w);
  else tx = c.bxhi_r[j] * (e - q) - c.bxlo_r[j] * (q - w);
  const T ty = by_hi * (n - q) - by_lo * (q - s);
  const T l = tx + ty;
  if constexpr (CMB == kAdj) return (T(2) * io.p0[j] + l) - io.pp0[j];
  const T k = KREG ? c.k : c.krow[j];
  if constexpr (CMB == kFwd) return (T(2) * q - io.pp0[j]) + k * l;
  return k * l;
}

// Explicit vectors of the build's width (build.py passes DL_VECTOR_BITS on x86) for the rz ring
// form's loop: written as the auto-vectorised loop, GCC reads q0[j + 1] (or q0[j - 1]) twice as
// memory operands; here each is one load held in a register (7 loads a cell: the unit stencil's
// 6 and g), and the arithmetic is the scalar loop's, cell for cell.
#if defined(DL_VECTOR_BITS) && defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__)) && \
    ((DL_VECTOR_BITS == 512 && defined(__AVX512F__)) || (DL_VECTOR_BITS == 256 && defined(__AVX__)))
#define DL_RING_VECTORS 1
typedef float DlVf __attribute__((vector_size(DL_VECTOR_BITS / 8)));
typedef double DlVd __attribute__((vector_size(DL_VECTOR_BITS / 8)));
template <typename T>
struct DlVec;
template <>
struct DlVec<float> {
  using V = DlVf;
};
template <>
struct DlVec<double> {
  using V = DlVd;
};
template <typename V, typename T>
static inline V dl_load(const T* p) {
  V v;
  std::memcpy(&v, p, sizeof(V));
  return v;
}
// a register value the compiler may not re-read from memory
template <typename V>
static inline V dl_held(V v) {
#if DL_VECTOR_BITS > 256
  __asm__("" : "+v"(v));
#else
  __asm__("" : "+x"(v));
#endif
  return v;
}
#endif

template <typename T, int BX, int BY, bool KREG, int CMB>
static void row_kernel(const RowCtx<T>& c, const RowIO<T>& io, int64_t ny) {
  const T* __restrict qm = io.qm;
  const T* __restrict q0 = io.q0;
  const T* __restrict qp = io.qp;
  const T* __restrict p0 = io.p0;
  const T* pp0 = io.pp0;
  T* out = io.out;
  const T* __restrict krow = c.krow;
  const T* __restrict bxlo = c.bxlo_r;
  const T* __restrict bxhi = c.bxhi_r;
  const T* __restrict cyl = c.cyl;
  const T* __restrict cyh = c.cyh;
  const T* __restrict cyg = c.cyg;
  const T k = c.k, c0 = c.c0, bxl = c.bxlo, bxh = c.bxhi, byv = c.by;
  if (ny == 1) {
    out[0] = edge_cell<T, BX, KREG, CMB>(c, io, 0, T(0), T(0), c.by_first_lo, c.by_last_hi);
    return;
  }
  const T first = edge_cell<T, BX, KREG, CMB>(c, io, 0, T(0), q0[1], c.by_first_lo, c.by_first_hi);
  const T last = edge_cell<T, BX, KREG, CMB>(c, io, ny - 1, q0[ny - 2], T(0), c.by_last_lo, c.by_last_hi);
  constexpr bool UNIT = BX == kUnit && BY == kUnit;
  constexpr bool RING = BX == kUnit && BY == kMetric;
  int64_t j0 = 1;
#ifdef DL_RING_VECTORS
  if constexpr (RING && KREG && CMB == kFwd) {
    using V = typename DlVec<T>::V;
    constexpr int64_t W = int64_t(sizeof(V) / sizeof(T));
    const V kv = V{} + k, c0v = V{} + c0;
    for (; j0 + W <= ny - 1; j0 += W) {
      const int64_t j = j0;
      const V n = dl_held(dl_load<V>(q0 + j + 1)), s = dl_held(dl_load<V>(q0 + j - 1));
      const V e = dl_load<V>(qp + j), w = dl_load<V>(qm + j), q = dl_load<V>(q0 + j);
      const V ns = n + s;
      const V sum = ((e + w) + ns) + dl_load<V>(cyg + j) * (T(2) * n - ns);
      const V r = (c0v * q - dl_load<V>(pp0 + j)) + kv * sum;
      std::memcpy(out + j, &r, sizeof(V));
    }
  }
#endif
#pragma GCC ivdep
  for (int64_t j = j0; j < ny - 1; ++j) {
    const T q = q0[j], e = qp[j], w = qm[j], n = q0[j + 1], s = q0[j - 1];
    T l, sum;
    if constexpr (UNIT) {
      sum = ((e + w) + n) + s;
      l = sum - T(4) * q;
    } else if constexpr (RING) {
      // (n + s) + g (n - s) with n - s as 2 n - (n + s) (exact but for the rounding of n + s, which
      // g <= 1/3 scales down): s and n each read once, 7 loads a cell (the unit stencil's 6 and g)
      const T ns = n + s;
      sum = ((e + w) + ns) + cyg[j] * (T(2) * n - ns);
      l = sum - T(4) * q;
    } else {
      T tx, ty;
      if constexpr (BX == kUnit) tx = (e + w) - T(2) * q;
      else if constexpr (BX == kReg) tx = bxh * (e - q) - bxl * (q - w);
      else tx = bxhi[j] * (e - q) - bxlo[j] * (q - w);
      if constexpr (BY == kUnit) ty = (n + s) - T(2) * q;
      else if constexpr (BY == kReg) ty = byv * (n - q) - byv * (q - s);
      else ty = cyh[j] * (n - q) - cyl[j] * (q - s);
      l = tx + ty;
      sum = l;
    }
    if constexpr (CMB == kFwd) {
      if constexpr ((UNIT || RING) && KREG) out[j] = (c0 * q - pp0[j]) + k * sum;
      else out[j] = (T(2) * q - pp0[j]) + (KREG ? k : krow[j]) * l;
    } else if constexpr (CMB == kD) {
      out[j] = (KREG ? k : krow[j]) * l;
    } else {
      out[j] = (T(2) * p0[j] + l) - pp0[j];
    }
  }
  out[0] = first;
  out[ny - 1] = last;
}


// The isotropic stencil (operators._across_faces) on uniform faces (one density, no obstacles:
// face conductances are the window's 0/1 masks and the rz metric). Each face difference is
// averaged across its face by [1, 10, 1] / 12; as the filters are linear and the x faces'
// conductances are one value per row, the row reads
//   L = S(D) + cyh (P_(j+1) - P_j) - cyl (P_j - P_(j-1)),
//   D = bxhi (qp - q0) - bxlo (q0 - qm)                  (the x second difference),
//   S(v)_j = v_j + (rh_j (v_(j+1) - v_j) - rl_j (v_j - v_(j-1))) / 12   (filter across x faces:
//            rh, rl the ring areas (j + 1, j) / (j + 1/2) on an rz grid, 1 on a plane one, 0 past
//            the window's ends: a mirror),
//   P = q0 + (ap (qp - q0) - am (q0 - qm)) / 12           (filter across y faces; am, ap = 0 at
//            the window's first / last row),
// two passes over a row: D and P into per-thread scratch, then the update (~22 flops a cell).
template <typename T, bool KREG, int CMB, bool FAST>
static void row_iso(const RowCtx<T>& c, const RowIO<T>& io, int64_t ny) {
  thread_local std::vector<T> scratch;
  if (int64_t(scratch.size()) < 2 * ny + 4) scratch.assign(2 * ny + 4, T(0));
  T* __restrict D = scratch.data() + 1;       // D[-1] = D[ny] = 0 (never written)
  T* __restrict P = scratch.data() + ny + 3;  // P[-1] = P[ny] = 0 (FAST: E = q0 + D / 6)
  const T* __restrict qm = io.qm;
  const T* __restrict q0 = io.q0;
  const T* __restrict qp = io.qp;
  const T* pp0 = io.pp0;
  T* out = io.out;
  const T* __restrict krow = c.krow;
  const T* __restrict cyl = c.cyl;
  const T* __restrict cyh = c.cyh;
  const T* __restrict rl = c.rl;
  const T* __restrict rh = c.rh;
  const T k = c.k, bxl = c.bxlo, bxh = c.bxhi, am = c.am, ap = c.ap;
  constexpr T w = T(1.0 / 12.0);
  auto put = [&](int64_t j, T l) {
    if constexpr (CMB == kFwd) out[j] = (T(2) * q0[j] - pp0[j]) + (KREG ? k : krow[j]) * l;
    else out[j] = (KREG ? k : krow[j]) * l;
  };
  if constexpr (FAST) {
    // an inner row with unit x faces: P = q0 + D / 12 and, inside the row (where the y
    // conductances are the filter's weights, which sum to 2), S(D) + L_y(P) = D + L_y(q0 + D / 6):
    // the Mehrstellen form, one ring-form y stencil
#pragma GCC ivdep
    for (int64_t j = 0; j < ny; ++j) {
      const T x0 = q0[j];
      const T d = (qp[j] + qm[j]) - T(2) * x0;
      D[j] = d;
      P[j] = x0 + d * T(1.0 / 6.0);
    }
#pragma GCC ivdep
    for (int64_t j = 1; j < ny - 1; ++j) put(j, D[j] + ((rh[j] * P[j + 1] + rl[j] * P[j - 1]) - T(2) * P[j]));
    // the row's two end cells in the general form (P = q0 + D / 12 there)
    for (int64_t j : {int64_t(0), ny - 1}) {
      if (j > 0 && ny == 1) break;
      const T d = D[j], p = q0[j] + d * w;
      const T pn = j + 1 < ny ? q0[j + 1] + D[j + 1] * w : T(0);
      const T ps = j > 0 ? q0[j - 1] + D[j - 1] * w : T(0);
      put(j, (d + (rh[j] * (D[j + 1] - d) - rl[j] * (d - D[j - 1])) * w) + (cyh[j] * (pn - p) - cyl[j] * (p - ps)));
    }
  } else {
#pragma GCC ivdep
    for (int64_t j = 0; j < ny; ++j) {
      const T x0 = q0[j], up = qp[j] - x0, dn = x0 - qm[j];
      D[j] = bxh * up - bxl * dn;
      P[j] = x0 + (ap * up - am * dn) * w;
    }
#pragma GCC ivdep
    for (int64_t j = 0; j < ny; ++j) {
      const T d = D[j], p = P[j];
      put(j, (d + (rh[j] * (D[j + 1] - d) - rl[j] * (d - D[j - 1])) * w) + (cyh[j] * (P[j + 1] - p) - cyl[j] * (p - P[j - 1])));
    }
  }
}


// The isotropic stencil with face-conductance arrays (obstacles, a density or speed map):
// operators._across_faces as written, M g = b g + T / 12 with the edge weights min(b_j, b_k)
// (times the ring boundary's area on an rz grid's x faces): x faces i and i + 1 from the q rows
// and the bx rows, y faces of row i from q rows i - 1, i, i + 1 and their by rows.
// the ny + 1 y-face differences of a q row (zero beyond the row's ends)
template <typename T>
static inline void y_differences(const T* __restrict q, T* __restrict d, int64_t ny) {
  d[0] = q[0];
#pragma GCC ivdep
  for (int64_t f = 1; f < ny; ++f) d[f] = q[f] - q[f - 1];
  d[ny] = -q[ny - 1];
}

// a y face's isotropic value from its differences in rows i - 1, i, i + 1 (gm, g0, gp) and their
// conductances (bm, b0, bp): b0 g0 + (edge to row i + 1 - edge to row i - 1) / 12, the edges
// weighted min(b, b'); am, ap = 0 where row i - 1 / i + 1 is outside the window
template <typename T>
static inline T iso_y_face(T gm, T g0, T gp, T bm, T b0, T bp, T am, T ap) {
  const T mp = b0 < bp ? b0 : bp, mm = bm < b0 ? bm : b0;
  return b0 * g0 + (ap * (gp - g0) * mp - am * (g0 - gm) * mm) * T(1.0 / 12.0);
}

template <typename T, bool KREG, int CMB>
static void row_iso_faces(const RowCtx<T>& c, const RowIO<T>& io, int64_t ny) {
  thread_local std::vector<T> scratch;
  const int64_t n1 = ny + 1;
  if (int64_t(scratch.size()) < 9 * n1 + 8) scratch.assign(9 * n1 + 8, T(0));
  T* zl = scratch.data();
  T* zh = zl + n1;
  T* g = zh + n1;
  T* e = g + n1;          // edge values between columns j and j + 1 (ny - 1)
  T* yf = e + n1;         // ny + 1 y-face values
  T* gm = yf + n1;        // y-face differences of rows i - 1, i, i + 1 (ny + 1 each)
  T* g0 = gm + n1;
  T* gp = g0 + n1;
  const T* __restrict qm = io.qm;
  const T* __restrict q0 = io.q0;
  const T* __restrict qp = io.qp;
  const T* pp0 = io.pp0;
  T* out = io.out;
  const T* __restrict rh = c.rh;  // the ring boundaries' weights (j + 1 between columns j, j + 1)
  const T* __restrict inva = c.inva;
  constexpr T w = T(1.0 / 12.0);
  // x face between rows lo and hi with conductances b (ny values)
  auto xface = [&](const T* __restrict lo, const T* __restrict hi, const T* __restrict b, T* __restrict dst) {
#pragma GCC ivdep
    for (int64_t j = 0; j < ny; ++j) g[j] = hi[j] - lo[j];
#pragma GCC ivdep
    for (int64_t j = 0; j + 1 < ny; ++j) {
      const T lo_b = b[j] < b[j + 1] ? b[j] : b[j + 1];
      e[j] = (g[j + 1] - g[j]) * lo_b * rh[j];
    }
    dst[0] = b[0] * g[0] + (ny > 1 ? e[0] : T(0)) * inva[0] * w;
#pragma GCC ivdep
    for (int64_t j = 1; j + 1 < ny; ++j) dst[j] = b[j] * g[j] + (e[j] - e[j - 1]) * inva[j] * w;
    if (ny > 1) dst[ny - 1] = b[ny - 1] * g[ny - 1] - e[ny - 2] * inva[ny - 1] * w;
  };
  xface(qm, q0, c.bxlo_r, zl);
  xface(q0, qp, c.bxhi_r, zh);
  y_differences(qm, gm, ny);
  y_differences(q0, g0, ny);
  y_differences(qp, gp, ny);
  const T* __restrict bm = c.bym;
  const T* __restrict b0 = c.by0;
  const T* __restrict bp = c.byp;
  const T am = c.am, ap = c.ap;
#pragma GCC ivdep
  for (int64_t f = 0; f <= ny; ++f) yf[f] = iso_y_face(gm[f], g0[f], gp[f], bm[f], b0[f], bp[f], am, ap);
  const T* __restrict cyl = c.cyl;
  const T* __restrict cyh = c.cyh;
  const T* __restrict krow = c.krow;
#pragma GCC ivdep
  for (int64_t j = 0; j < ny; ++j) {
    const T l = (zh[j] - zl[j]) + (cyh[j] * yf[j + 1] - cyl[j] * yf[j]);
    if constexpr (CMB == kFwd) out[j] = (T(2) * q0[j] - pp0[j]) + (KREG ? c.k : krow[j]) * l;
    else out[j] = (KREG ? c.k : krow[j]) * l;
  }
}

template <typename T>
using RowFn = void (*)(const RowCtx<T>&, const RowIO<T>&, int64_t);

template <typename T, int CMB>
RowFn<T> pick_row(int bx, int by, bool kreg) {
#define DL_CASE(X, Y, K) \
  if (bx == X && by == Y && kreg == K) return &row_kernel<T, X, Y, K, CMB>;
  DL_CASE(kUnit, kUnit, true) DL_CASE(kReg, kUnit, true) DL_CASE(kUnit, kReg, true)
  DL_CASE(kReg, kReg, true) DL_CASE(kVec, kVec, true) DL_CASE(kUnit, kVec, true) DL_CASE(kReg, kVec, true)
  DL_CASE(kUnit, kUnit, false) DL_CASE(kReg, kUnit, false) DL_CASE(kUnit, kReg, false)
  DL_CASE(kReg, kReg, false) DL_CASE(kVec, kVec, false) DL_CASE(kUnit, kVec, false) DL_CASE(kReg, kVec, false)
  DL_CASE(kUnit, kMetric, true) DL_CASE(kUnit, kMetric, false)
#undef DL_CASE
  return nullptr;
}


template <typename T>
struct LayerArgs;  // layers.h

template <typename T>
struct LeapfrogArgs {
  int64_t nx, ny, n_steps;
  int n_threads, levels;
  bool bands;   // row bands with a barrier per step instead of the pipeline (no q buffering)
  bool iso;     // the isotropic stencil (uniform faces only: 0/1 window masks and the rz metric)
  int combine;  // kFwd (plain or with extras) or kAdj
  T* p;         // P(t) in, the latest field out
  T* pp;        // P(t-1) in, the previous field out
  Coef<T> K, bx, by, qs, keep, sponge;
  Coef<T> my_lo, my_hi;  // rz metric: factors of each cell's low and high y face (per column)
  double eta;  // viscous coefficient (0: none); q = qs ((1 + eta) p - eta pp)
  // air absorption (lattice.coefficients.AirRelaxation; rq[0] == nullptr: lossless, none of it
  // runs): the operand adds r_eta (p - pp) + eps_0 Q_0 + eps_1 Q_1 (before qs), and after the
  // sources Q_i = a_i Q_i + g_i (P(t+1) - P(t)), in place, row by row
  T* rq[2] = {nullptr, nullptr};
  T r_eta = T(0), r_eps[2] = {T(0), T(0)}, r_a[2] = {T(0), T(0)}, r_g[2] = {T(0), T(0)};
  CellOps<T> cells;
  const LayerArgs<T>* layers = nullptr;  // PML layers (nullptr: none)
};

// per-row coefficients and the row kernel that fits them
template <typename T>
struct RowPlan {
  std::vector<RowFn<T>> fn;
  std::vector<RowCtx<T>> ctx;        // coefficient fields only
  std::vector<T> bx_full, by_full;  // both axes as full arrays where one is and the other not
  std::vector<T> cy_lo, cy_hi;      // metric x conductance per cell face (a row, or the grid)
  std::vector<T> cy_g, m_g;         // the ring form's g per column: of cy_lo / cy_hi (one row), of m_lo / m_hi
  std::vector<T> r_lo, r_hi;        // isotropic stencil: the filter's weights across x faces
  std::vector<T> inva, m_lo, m_hi;  // isotropic stencil with face arrays: 1 / ring area, the metric
};


template <typename T>
Coef<T> materialise(const Coef<T>& c, int64_t rows, int64_t cols, std::vector<T>& dst);

// the isotropic stencil with face arrays: bx and by as full arrays, the metric and the filter's
// weights one row each
template <typename T>
bool plan_iso_faces(const LeapfrogArgs<T>& a, int cmb, RowPlan<T>& plan) {
  const int64_t nx = a.nx, ny = a.ny;
  const bool metric = a.my_lo.present();
  const Coef<T> bx = materialise(a.bx, nx + 1, ny, plan.bx_full);
  const Coef<T> by = materialise(a.by, nx, ny + 1, plan.by_full);
  plan.m_lo.assign(ny, T(1));
  plan.m_hi.assign(ny, T(1));
  plan.r_hi.assign(ny, T(1));
  plan.inva.assign(ny, T(1));
  for (int64_t j = 0; j < ny; ++j) {
    if (metric) {
      plan.m_lo[j] = a.my_lo.at(0, j);
      plan.m_hi[j] = a.my_hi.at(0, j);
      plan.r_hi[j] = T(double(j) + 1.0);  // the ring boundary's area between j, j + 1; the ring's j + 1/2
      plan.inva[j] = T(1.0 / (double(j) + 0.5));
    }
  }
  plan.fn.resize(nx);
  plan.ctx.resize(nx);
  const bool kreg = a.K.in_register();
  for (int64_t i = 0; i < nx; ++i) {
    RowCtx<T>& c = plan.ctx[i];
    c = RowCtx<T>{};
    if (kreg) c.k = a.K.value(i);
    else c.krow = a.K.row(i);
    c.bxlo_r = bx.row(i);
    c.bxhi_r = bx.row(i + 1);
    c.by0 = by.row(i);
    c.bym = i > 0 ? by.row(i - 1) : c.by0;
    c.byp = i + 1 < nx ? by.row(i + 1) : c.by0;
    c.cyl = plan.m_lo.data();
    c.cyh = plan.m_hi.data();
    c.rh = plan.r_hi.data();
    c.inva = plan.inva.data();
    c.am = i > 0 ? T(1) : T(0);
    c.ap = i + 1 < nx ? T(1) : T(0);
    if (cmb == kFwd) plan.fn[i] = kreg ? &row_iso_faces<T, true, kFwd> : &row_iso_faces<T, false, kFwd>;
    else plan.fn[i] = kreg ? &row_iso_faces<T, true, kD> : &row_iso_faces<T, false, kD>;
  }
  return true;
}

// the isotropic stencil's plan: x faces one value per row (window masks), y faces and the rz
// metric one shared row of factors; anything else is declined (false)
template <typename T>
bool plan_iso(const LeapfrogArgs<T>& a, int cmb, RowPlan<T>& plan) {
  const int64_t nx = a.nx, ny = a.ny;
  const bool metric = a.my_lo.present();
  if (cmb == kAdj) return false;
  if (metric && (a.my_lo.mode == kFull || a.my_lo.mode == kPerRow || a.my_hi.mode == kFull || a.my_hi.mode == kPerRow))
    return false;
  const bool faces = (a.bx.present() && !a.bx.in_register()) ||
                     (a.by.present() && a.by.mode != kScalar && a.by.mode != kPerCol);
  if (faces) return plan_iso_faces(a, cmb, plan);
  plan.cy_lo.assign(ny, T(0));
  plan.cy_hi.assign(ny, T(0));
  plan.r_lo.assign(ny, T(0));
  plan.r_hi.assign(ny, T(0));
  for (int64_t j = 0; j < ny; ++j) {
    const T ml = metric ? a.my_lo.at(0, j) : T(1), mh = metric ? a.my_hi.at(0, j) : T(1);
    plan.cy_lo[j] = a.by.present() ? ml * a.by.at(0, j) : ml;
    plan.cy_hi[j] = a.by.present() ? mh * a.by.at(0, j + 1) : mh;
    // the ring boundaries' areas j + 1 (between rings j and j + 1) over the ring's area j + 1/2
    plan.r_lo[j] = j == 0 ? T(0) : (metric ? T(double(j) / (double(j) + 0.5)) : T(1));
    plan.r_hi[j] = j + 1 == ny ? T(0) : (metric ? T((double(j) + 1.0) / (double(j) + 0.5)) : T(1));
  }
  plan.fn.resize(nx);
  plan.ctx.resize(nx);
  const bool kreg = a.K.in_register();
  for (int64_t i = 0; i < nx; ++i) {
    RowCtx<T>& c = plan.ctx[i];
    c = RowCtx<T>{};
    if (kreg) c.k = a.K.value(i);
    else c.krow = a.K.row(i);
    c.bxlo = a.bx.present() ? a.bx.value(i) : T(1);
    c.bxhi = a.bx.present() ? (a.bx.mode == kScalar ? c.bxlo : a.bx.value(i + 1)) : T(1);
    c.cyl = plan.cy_lo.data();
    c.cyh = plan.cy_hi.data();
    c.rl = plan.r_lo.data();
    c.rh = plan.r_hi.data();
    c.am = i > 0 ? T(1) : T(0);
    c.ap = i + 1 < nx ? T(1) : T(0);
    // inner rows with unit x faces take the Mehrstellen form (the y weights are the filter's
    // inside a row: the rz metric, or 1 on a plane grid, whose y masks only close the end faces)
    const bool fast = c.am == T(1) && c.ap == T(1) && c.bxlo == T(1) && c.bxhi == T(1);
#define DL_ISO(K_, C_) (fast ? &row_iso<T, K_, C_, true> : &row_iso<T, K_, C_, false>)
    if (cmb == kFwd) plan.fn[i] = kreg ? DL_ISO(true, kFwd) : DL_ISO(false, kFwd);
    else plan.fn[i] = kreg ? DL_ISO(true, kD) : DL_ISO(false, kD);
#undef DL_ISO
  }
  return true;
}

template <typename T>
Coef<T> materialise(const Coef<T>& c, int64_t rows, int64_t cols, std::vector<T>& dst) {
  dst.assign(rows * cols, T(1));
  if (c.present())
    for (int64_t i = 0; i < rows; ++i)
      for (int64_t j = 0; j < cols; ++j) dst[i * cols + j] = c.at(i, j);
  Coef<T> r;
  r.data = dst.data();
  r.mode = kFull;
  r.ld = cols;
  return r;
}

// whether a row's n values are one value (no early exit: the loop vectorises)
template <typename T>
inline bool all_equal(const T* __restrict r, int64_t n) {
  const T r0 = r[0];
  int bad = 0;
  for (int64_t j = 1; j < n; ++j) bad |= !(r[j] == r0);
  return bad == 0;
}

// the metric's per-cell y conductances of row i (m_lo b_lo, m_hi b_hi, as the reference forms them)
template <typename T>
inline void fill_cy(const Coef<T>& my_lo, const Coef<T>& my_hi, const Coef<T>& by, int64_t i, int64_t ny, T* lo, T* hi) {
  for (int64_t j = 0; j < ny; ++j) {
    const T ml = my_lo.at(i, j), mh = my_hi.at(i, j);
    lo[j] = by.present() ? ml * by.at(i, j) : ml;
    hi[j] = by.present() ? mh * by.at(i, j + 1) : mh;
  }
}

template <typename T>
bool plan_rows(const LeapfrogArgs<T>& a, int cmb, RowPlan<T>& plan) {
  const int64_t nx = a.nx, ny = a.ny;
  Coef<T> bx = a.bx, by = a.by;
  const bool metric = a.my_lo.present();
  const bool bx_vec = bx.mode == kPerCol || bx.mode == kFull;
  const bool by_vec = by.mode == kFull || (by.mode == kPerCol && !all_one(by.data + 1, ny - 1));
  if (bx_vec && !by_vec) by = materialise(a.by, nx, ny + 1, plan.by_full);  // x vectors need y vectors
  // the metric: per-cell y conductances m_lo b_lo and m_hi b_hi (products as the reference forms them)
  bool cy_rows = false;
  if (metric) {
    cy_rows = by.mode == kFull || by.mode == kPerRow || a.my_lo.mode == kFull || a.my_hi.mode == kFull;
    const int64_t rows = cy_rows ? nx : 1;
    plan.cy_lo.resize(rows * ny);
    plan.cy_hi.resize(rows * ny);
    if (!cy_rows) fill_cy(a.my_lo, a.my_hi, by, 0, ny, plan.cy_lo.data(), plan.cy_hi.data());
  }
  // the ring form: the metric's interior factors sum to 2 (to rounding) in one shared row
  bool ring_form = metric && !cy_rows && cmb == kFwd && ny > 2;
  for (int64_t j = 1; ring_form && j < ny - 1; ++j) {
    const T d = plan.cy_lo[j] + plan.cy_hi[j] - T(2);
    ring_form = (d < T(0) ? -d : d) <= T(8) * std::numeric_limits<T>::epsilon();
  }
  auto half_difference = [ny](const std::vector<T>& lo, const std::vector<T>& hi, std::vector<T>& g) {
    g.resize(ny);
    for (int64_t j = 0; j < ny; ++j) g[j] = (hi[j] - lo[j]) * T(0.5);
  };
  if (ring_form) half_difference(plan.cy_lo, plan.cy_hi, plan.cy_g);
  // rz rows of one material among face arrays: b times the ring form of the metric alone (its
  // interior factors summing to 2 in one shared row), K b as the coefficient
  bool metric_ring = metric && cy_rows && cmb == kFwd && ny > 2 && bx.mode == kFull && by.mode == kFull &&
                     a.my_lo.mode != kFull && a.my_lo.mode != kPerRow && a.my_hi.mode != kFull && a.my_hi.mode != kPerRow;
  if (metric_ring) {
    plan.m_lo.assign(ny, T(0));
    plan.m_hi.assign(ny, T(0));
    for (int64_t j = 0; j < ny; ++j) {
      plan.m_lo[j] = a.my_lo.at(0, j);
      plan.m_hi[j] = a.my_hi.at(0, j);
    }
    for (int64_t j = 1; metric_ring && j < ny - 1; ++j) {
      const T d = plan.m_lo[j] + plan.m_hi[j] - T(2);
      metric_ring = (d < T(0) ? -d : d) <= T(8) * std::numeric_limits<T>::epsilon();
    }
    if (metric_ring) half_difference(plan.m_lo, plan.m_hi, plan.m_g);
  }
  plan.fn.resize(nx);
  plan.ctx.resize(nx);
  // A row whose coefficients are one value (a layered medium, the rows that miss an obstacle) runs
  // the kernel of register coefficients: the arrays are not streamed for it
  auto uniform = [](const T* r, int64_t n) { return all_equal(r, n); };
  auto plan_row = [&](int64_t i) -> bool {
    RowCtx<T>& c = plan.ctx[i];
    c = RowCtx<T>{};
    bool kreg = a.K.in_register();
    if (!kreg && cmb != kAdj && a.K.mode == kFull && uniform(a.K.row(i), ny)) {
      kreg = true;
      c.k = a.K.row(i)[0];
      c.c0 = T(2) - T(4) * c.k;
    } else if (kreg) {
      c.k = a.K.value(i);
      c.c0 = T(2) - T(4) * c.k;
    } else {
      c.krow = a.K.row(i);
    }
    int bxm = kUnit, bym = kUnit;
    if (bx.in_register()) {
      c.bxlo = bx.value(i);
      c.bxhi = bx.mode == kScalar ? c.bxlo : bx.value(i + 1);
      bxm = (c.bxlo == T(1) && c.bxhi == T(1)) ? kUnit : kReg;
    } else if (bx.mode == kFull && uniform(bx.row(i), ny) && uniform(bx.row(i + 1), ny)) {
      c.bxlo = bx.row(i)[0];
      c.bxhi = bx.row(i + 1)[0];
      bxm = (c.bxlo == T(1) && c.bxhi == T(1)) ? kUnit : kReg;
    } else if (bx.present()) {
      c.bxlo_r = bx.row(i);
      c.bxhi_r = bx.mode == kPerCol ? c.bxlo_r : bx.row(i + 1);
      bxm = kVec;
    }
    c.by_first_lo = c.by_first_hi = c.by_last_lo = c.by_last_hi = T(1);
    // a row taking the metric's ring form below needs no per-cell y conductances (filled lazily:
    // they were a pass over the grid at every call)
    const bool ring_row = metric_ring && kreg && (bxm == kReg || bxm == kUnit) && c.bxlo == c.bxhi &&
                          c.bxlo > T(0) && uniform(by.row(i), ny + 1) && by.row(i)[0] == c.bxlo;
    if (metric && cy_rows && !ring_row)
      fill_cy(a.my_lo, a.my_hi, by, i, ny, plan.cy_lo.data() + i * ny, plan.cy_hi.data() + i * ny);
    if (metric) {
      c.cyl = plan.cy_lo.data() + (cy_rows ? i * ny : 0);
      c.cyh = plan.cy_hi.data() + (cy_rows ? i * ny : 0);
      bym = kVec;
    } else if (by.in_register()) {
      c.by = by.value(i);
      c.by_first_lo = c.by_first_hi = c.by_last_lo = c.by_last_hi = c.by;
      bym = c.by == T(1) ? kUnit : kReg;
    } else if (by.present()) {
      const T* r = by.row(i);
      c.cyl = r;
      c.cyh = r + 1;
      // one value inside (e.g. unit with a rigid window's closed faces): only the edge cells differ
      bym = kVec;
      if (bxm != kVec && uniform(r + 1, ny - 1)) {
        c.by = r[1];
        bym = c.by == T(1) ? kUnit : kReg;
        c.by_first_lo = r[0];
        c.by_first_hi = r[1];
        c.by_last_lo = r[ny - 1];
        c.by_last_hi = r[ny];
      }
    }
    if (bym == kVec) {
      c.by_first_lo = c.cyl[0];
      c.by_first_hi = c.cyh[0];
      c.by_last_lo = c.cyl[ny - 1];
      c.by_last_hi = c.cyh[ny - 1];
    }
    if (ring_row) {
      const T b = c.bxlo;
      c.k = c.k * b;
      c.c0 = T(2) - T(4) * c.k;
      c.cyl = plan.m_lo.data();
      c.cyh = plan.m_hi.data();
      c.cyg = plan.m_g.data();
      c.by_first_lo = plan.m_lo[0];
      c.by_first_hi = plan.m_hi[0];
      c.by_last_lo = plan.m_lo[ny - 1];
      c.by_last_hi = plan.m_hi[ny - 1];
      bxm = kUnit;
      bym = kMetric;
    }
    // 2-D rows of one material (every face of the row one conductance b, K one value): K b as
    // the coefficient of the unit stencil, as the rz rows' ring form above
    if (!metric && cmb == kFwd && kreg && bxm == kReg && bym == kReg && c.bxlo == c.bxhi && c.by == c.bxlo &&
        c.bxlo > T(0) && c.by_first_lo == c.by && c.by_first_hi == c.by && c.by_last_lo == c.by &&
        c.by_last_hi == c.by) {
      c.k = c.k * c.bxlo;
      c.c0 = T(2) - T(4) * c.k;
      c.by_first_lo = c.by_first_hi = c.by_last_lo = c.by_last_hi = T(1);
      bxm = kUnit;
      bym = kUnit;
    }
    if (bxm == kVec && bym != kVec) return false;  // (by was materialised above)
    if (ring_form && bxm == kUnit && bym == kVec) {
      bym = kMetric;
      c.cyg = plan.cy_g.data();
    }
    RowFn<T> f = cmb == kAdj ? pick_row<T, kAdj>(bxm, bym, kreg)
                             : (cmb == kD ? pick_row<T, kD>(bxm, bym, kreg) : pick_row<T, kFwd>(bxm, bym, kreg));
    if (!f) return false;
    plan.fn[i] = f;
    return true;
  };
  // the rows' plans on the call's threads (a pass over K and the face arrays when they are full:
  // run serially it was ~3 % of a two-thread call of the full 840x630 scene)
  const int nt = nx * ny >= (int64_t(1) << 16) ? std::max(1, a.n_threads) : 1;
  std::vector<char> ok(nt, 1);
  parallel(nt, [&](int t) {
    for (int64_t i = nx * t / nt, e = nx * (t + 1) / nt; i < e; ++i)
      if (!plan_row(i)) {
        ok[t] = 0;
        return;
      }
  });
  return std::all_of(ok.begin(), ok.end(), [](char v) { return v != 0; });
}

}  // namespace dl
