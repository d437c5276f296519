// PML layers: the split-field form on the layer's boxes, row by row inside the leapfrog's pipeline
// (part of the native kernels: included by lattice.cc, one translation unit)
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <optional>
#include <vector>

#include "stencil.h"

// the box rows' loops on 256-bit vectors where the kernels use 512: a box row is often 20
// columns (16 + 4 scalar at 512 bits, 8 + 8 + a 128-bit epilogue at 256)
#if defined(__AVX512F__) && !defined(DL_LAYER_VW)
#define DL_LAYER_VW __attribute__((target("prefer-vector-width=256")))
#elif !defined(DL_LAYER_VW)
#define DL_LAYER_VW
#endif

namespace dl {

// ----------------------------------------------------------------------------------------------
// PML layers (stepper._step_layers): the leapfrog runs on every row; the split-field form runs on
// the layer's boxes only (coefficients.layer_boxes: rows [r0, r1) x columns [c0, c1), disjoint),
// whose cells take the sum of their parts:
//   wx = axf wx + bxf (b_x (q_i - q_{i-1}))      (the box's faces along x, its outer two included)
//   wy = ayf wy + byf (b_y (q_j - q_{j-1}))
//   px = axc px + bxc (K (wx_{i+1} - wx_i)),  py = ayc py + byc (K ((mh wy_{j+1} - ml wy_j) + C));
//   keep px, py;  P = px + py
// with the rz r_hi layer's ring correction C = decay C + drive (the ring's two y faces, new and
// old) on the outer w columns. Row i of a step updates the box's x face i + 1 (and face r0 at its
// first row) from q rows i, i + 1, its y faces and parts of row i: the pipeline's order for the
// leapfrog (step L + 1 takes row i after step L finished row i + 1) keeps one copy of each.

// a coefficient's row i as a plain pointer: its own row, or a buffer holding its one value
template <typename T>
struct RowBuf {
  std::vector<T> v;
  T value = T(0);
  bool filled = false;
  const T* get(const Coef<T>& c, int64_t i, int64_t n) {
    if (!c.in_register()) return c.row(i);
    const T x = c.value(i);
    if (!filled || !(x == value) || int64_t(v.size()) < n) {
      v.assign(n, x);
      value = x;
      filled = true;
    }
    return v.data();
  }
};

template <typename T>
struct LayerBox {
  int64_t r0, r1, c0, c1;
  T *px, *py;  // (r1 - r0, c1 - c0)
  T* wx;       // (r1 - r0 + 1, c1 - c0): x faces r0 .. r1
  T* wy;       // (r1 - r0, c1 - c0 + 1): y faces c0 .. c1 of each row
  T* cr;       // (r1 - r0, w): the ring correction on columns [ny - w, ny), or nullptr
};

template <typename T>
struct LayerArgs {
  std::vector<LayerBox<T>> boxes;
  std::vector<std::vector<int>> of_row;  // the boxes holding each row (at most three)
  std::vector<char> whole_row;           // rows every column of which lies in a box
  Coef<T> axc, bxc, axf, bxf;            // one value per row: (nx, 1), (nx + 1, 1)
  Coef<T> ayc, byc, ayf, byf;            // one vector for all rows: (1, ny), (1, ny + 1)
  const T *rad_decay = nullptr, *rad_drive = nullptr;
  int64_t w = 0;
  bool iso_faces = false;  // the isotropic stencil with face-conductance arrays: by as a full array
  std::vector<T> by_full;
};


// per-thread scratch of the layer rows
template <typename T>
struct LayerScratch {
  RowBuf<T> k, bxl, bxh, by, keep, ml, mh;
  std::vector<T> ones, old, d, P, e;
  std::vector<signed char> k_one;  // per row: K one value on the row (1), not (0), not yet known (-1)
  explicit LayerScratch(int64_t ny, int64_t w)
      : ones(ny + 2, T(1)), old(w + 1, T(0)), d(ny + 2, T(0)), P(ny + 2, T(0)), e(ny + 1, T(0)) {}
  // whether K is one value on row i (a register coefficient, or a row of one material), and which
  bool k_uniform(const Coef<T>& K, int64_t i, int64_t nx, int64_t ny, T* v) {
    if (K.in_register()) {
      *v = K.value(i);
      return true;
    }
    if (int64_t(k_one.size()) != nx) k_one.assign(nx, -1);
    const T* r = K.row(i);
    if (k_one[i] < 0) k_one[i] = all_equal(r, ny) ? 1 : 0;
    *v = r[0];
    return k_one[i] == 1;
  }
};

// the isotropic stencil's filter weights across x faces (rz: the ring areas (j + 1, j) / (j + 1/2);
// 0 past the row's ends: a mirror)
// (with face arrays: the ring boundaries' areas eh = j + 1 and 1 / (j + 1/2), 1 on a plane grid)
template <typename T>
struct IsoWeights {
  std::vector<T> rl, rh, eh, inva;
  IsoWeights(int64_t ny, bool ring) : rl(ny, T(0)), rh(ny, T(0)), eh(ny, T(1)), inva(ny, T(1)) {
    for (int64_t j = 0; j < ny; ++j) {
      rl[j] = j == 0 ? T(0) : (ring ? T(double(j) / (double(j) + 0.5)) : T(1));
      rh[j] = j + 1 == ny ? T(0) : (ring ? T((double(j) + 1.0) / (double(j) + 0.5)) : T(1));
      if (ring) {
        eh[j] = T(double(j) + 1.0);
        inva[j] = T(1.0 / (double(j) + 0.5));
      }
    }
  }
};

// x face f (the box's face kf) from q rows lo, hi: w = A w + B (b (hi - lo)), or with the
// isotropic stencil the difference filtered across the face ([1, 10, 1] / 12, uniform faces)
template <typename T>
inline void layer_x_face(const LeapfrogArgs<T>& a, const LayerArgs<T>& la, const IsoWeights<T>& iw,
                         const LayerBox<T>& b, int64_t kf, int64_t f, const T* __restrict lo, const T* __restrict hi,
                         LayerScratch<T>& S) {
  const int64_t ny = a.ny, c0 = b.c0, nc = b.c1 - b.c0;
  T* __restrict w = b.wx + kf * nc;
  const T A = la.axf.present() ? la.axf.at(f, 0) : T(1), B = la.bxf.present() ? la.bxf.at(f, 0) : T(1);
  if (la.iso_faces) {  // operators._across_faces: b d + (edge differences) / 12, edges weighted min(b, b')
    T* __restrict d = S.d.data() + 1;
    T* __restrict e = S.e.data();  // e[j]: the edge between columns j - 1 and j (0 at the window's ends)
    const int64_t j0 = std::max<int64_t>(c0 - 1, 0), j1 = std::min<int64_t>(b.c1 + 1, ny);
    for (int64_t j = j0; j < j1; ++j) d[j] = hi[j] - lo[j];
    const T* __restrict bb = a.bx.present() ? S.bxl.get(a.bx, f, ny) : S.ones.data();
    for (int64_t j = c0; j <= b.c1; ++j) {
      if (j == 0 || j == ny) {
        e[j] = T(0);
      } else {
        const T m = bb[j - 1] < bb[j] ? bb[j - 1] : bb[j];
        e[j] = (d[j] - d[j - 1]) * m * iw.eh[j - 1];
      }
    }
    constexpr T w12 = T(1.0 / 12.0);
    for (int64_t k = 0; k < nc; ++k) {
      const int64_t j = c0 + k;
      w[k] = A * w[k] + B * (bb[j] * d[j] + (e[j + 1] - e[j]) * iw.inva[j] * w12);
    }
    return;
  }
  if (a.iso) {
    T* __restrict d = S.d.data() + 1;  // d[-1] = d[ny] = 0
    const int64_t j0 = std::max<int64_t>(c0 - 1, 0), j1 = std::min<int64_t>(b.c1 + 1, ny);
    for (int64_t j = j0; j < j1; ++j) d[j] = hi[j] - lo[j];
    const T bb = a.bx.present() ? a.bx.at(f, 0) : T(1);  // uniform faces: the window's mask
    const T* __restrict rl = iw.rl.data();
    const T* __restrict rh = iw.rh.data();
    constexpr T w12 = T(1.0 / 12.0);
#pragma GCC ivdep
    for (int64_t k = 0; k < nc; ++k) {
      const int64_t j = c0 + k;
      const T g = d[j];
      w[k] = A * w[k] + B * (bb * (g + (rh[j] * (d[j + 1] - g) - rl[j] * (g - d[j - 1])) * w12));
    }
    return;
  }
  const T* __restrict bb = a.bx.present() ? S.bxl.get(a.bx, f, ny) : S.ones.data();
#pragma GCC ivdep
  for (int64_t k = 0; k < nc; ++k) {
    const int64_t j = c0 + k;
    w[k] = A * w[k] + B * (bb[j] * (hi[j] - lo[j]));
  }
}

// the y faces c0 .. c1 of row i (box row kr) from the q row q (zero beyond the window), and the
// rz ring correction of the row
template <typename T>
inline void layer_y_faces(const LeapfrogArgs<T>& a, const LayerArgs<T>& la, const LayerBox<T>& b, int64_t kr,
                          int64_t i, const T* __restrict q, const T* qm, const T* qp, LayerScratch<T>& S) {
  const int64_t ny = a.ny, c0 = b.c0, nc = b.c1 - b.c0;
  T* __restrict w = b.wy + kr * (nc + 1);
  const int64_t w_r = b.cr ? la.w : 0;
  T* old = S.old.data();
  if (w_r) std::copy(w + nc - w_r, w + nc + 1, old);  // the outer rings' faces before the update
  const T* __restrict bb = a.by.present() ? S.by.get(a.by, i, ny + 1) : S.ones.data();
  const T* __restrict ayf = la.ayf.present() ? la.ayf.row(0) : S.ones.data();
  const T* __restrict byf = la.byf.present() ? la.byf.row(0) : S.ones.data();
  if (la.iso_faces) {  // from the differences of rows i - 1, i, i + 1 and their by rows (iso_y_face)
    const int64_t n1 = ny + 1;
    const T* b0 = la.by_full.data() + i * n1;
    const T* bm = i > 0 ? b0 - n1 : b0;
    const T* bp = i + 1 < a.nx ? b0 + n1 : b0;
    const T am = i > 0 ? T(1) : T(0), ap = i + 1 < a.nx ? T(1) : T(0);
    auto diff = [&](const T* r, int64_t f) { return (f < ny ? r[f] : T(0)) - (f > 0 ? r[f - 1] : T(0)); };
    for (int64_t k = 0; k <= nc; ++k) {
      const int64_t f = c0 + k;
      w[k] = ayf[f] * w[k] + byf[f] * iso_y_face(diff(qm, f), diff(q, f), diff(qp, f), bm[f], b0[f], bp[f], am, ap);
    }
  } else {
    // the window's outer faces (zero beyond the row) apart, so the loop has no branch
    const int64_t kb = c0 == 0 ? 1 : 0, ke = b.c1 == ny ? nc : nc + 1;
    if (kb) w[0] = ayf[0] * w[0] + byf[0] * (bb[0] * (q[0] - T(0)));
    if (ke == nc) w[nc] = ayf[ny] * w[nc] + byf[ny] * (bb[ny] * (T(0) - q[ny - 1]));
    const T* __restrict qf = q + c0;
    const T* __restrict af = ayf + c0;
    const T* __restrict bf = byf + c0;
    const T* __restrict cf = bb + c0;
#pragma GCC ivdep
    for (int64_t k = kb; k < ke; ++k) w[k] = af[k] * w[k] + bf[k] * (cf[k] * (qf[k] - qf[k - 1]));
  }
  if (w_r) {
    T* __restrict c = b.cr + kr * w_r;
    const T* __restrict o = old;
#pragma GCC ivdep
    for (int64_t k = 0; k < w_r; ++k) {
      const int64_t kk = nc - w_r + k;  // the box's face of ring ny - w + k
      const T sum = ((w[kk + 1] + w[kk]) + o[k + 1]) + o[k];
      c[k] = la.rad_decay[k] * c[k] + la.rad_drive[k] * sum;
    }
  }
}

// a box row's parts: px, py (keep), P = px + py into o; RZ: the metric (m_hi w_(j+1) - m_lo w_j),
// plus the ring correction cr on the box's last w_r columns. kp == nullptr: the fast path (no
// keep, K is kv on the row), which also updates the x face i + 1 (whi, passed as an XFace) column
// by column before its use (whi is then not read); else kk_or_face is the K row.
template <typename T>
struct XFace {  // the x face above a box row: w = A w + B (b (hi - lo)), per column of the box
  T* w;
  const T *lo, *hi, *b;
  T A, B;
};

template <typename T, bool RZ>
DL_LAYER_VW inline void layer_parts(T* __restrict x, T* __restrict y, T* __restrict o, const T* __restrict wlo,
                        const T* __restrict whi, const T* __restrict wy, const T* __restrict ayc,
                        const T* __restrict byc, T Ax, T Bx, const void* kk_or_face, const T* __restrict kp, T kv,
                        const T* __restrict ml, const T* __restrict mh, const T* __restrict cr, int64_t nc, int64_t w_r) {
  const int64_t k_r = nc - w_r;
  auto dy = [&](int64_t k) {
    if constexpr (RZ) return mh[k] * wy[k + 1] - ml[k] * wy[k];
    else return wy[k + 1] - wy[k];
  };
  if (kp == nullptr) {  // the fast path: kk_or_face is the x face i + 1 (whi), K is kv
    const XFace<T>& f = *static_cast<const XFace<T>*>(kk_or_face);
    T* __restrict fw = f.w;
    const T* __restrict flo = f.lo;
    const T* __restrict fhi = f.hi;
    const T* __restrict fb = f.b;
    const T fA = f.A, fB = f.B;
#pragma GCC ivdep
    for (int64_t k = 0; k < k_r; ++k) {
      const T wh = fA * fw[k] + fB * (fb[k] * (fhi[k] - flo[k]));
      fw[k] = wh;
      const T xv = Ax * x[k] + Bx * (kv * (wh - wlo[k]));
      const T yv = ayc[k] * y[k] + byc[k] * (kv * dy(k));
      x[k] = xv;
      y[k] = yv;
      o[k] = xv + yv;
    }
#pragma GCC ivdep
    for (int64_t k = k_r; k < nc; ++k) {
      const T wh = fA * fw[k] + fB * (fb[k] * (fhi[k] - flo[k]));
      fw[k] = wh;
      const T xv = Ax * x[k] + Bx * (kv * (wh - wlo[k]));
      const T yv = ayc[k] * y[k] + byc[k] * (kv * (dy(k) + cr[k]));
      x[k] = xv;
      y[k] = yv;
      o[k] = xv + yv;
    }
    return;
  }
  const T* __restrict kk = static_cast<const T*>(kk_or_face);
#pragma GCC ivdep
  for (int64_t k = 0; k < k_r; ++k) {
    const T xv = kp[k] * (Ax * x[k] + Bx * (kk[k] * (whi[k] - wlo[k])));
    const T yv = kp[k] * (ayc[k] * y[k] + byc[k] * (kk[k] * dy(k)));
    x[k] = xv;
    y[k] = yv;
    o[k] = xv + yv;
  }
#pragma GCC ivdep
  for (int64_t k = k_r; k < nc; ++k) {
    const T xv = kp[k] * (Ax * x[k] + Bx * (kk[k] * (whi[k] - wlo[k])));
    const T yv = kp[k] * (ayc[k] * y[k] + byc[k] * (kk[k] * (dy(k) + cr[k])));
    x[k] = xv;
    y[k] = yv;
    o[k] = xv + yv;
  }
}

// The common case's box rows planned once per call (standard stencil, no keep, K one value on
// the row, face and metric coefficients held as arrays): the operands' pointers and the row's
// factors, so that a step's box row is its two loops (y faces; x face i + 1 and the parts).
// Same arithmetic as layer_x_face + layer_y_faces + layer_parts.
template <typename T>
struct LayerScratch;

template <typename T>
struct FastRow;

template <typename T>
using BoxRowFn = void (*)(const FastRow<T>&, const LayerArgs<T>&, int64_t, const T*, const T*, T*, LayerScratch<T>&);

template <typename T>
struct FastRow {
  T *x, *y, *wlo, *fw, *wy, *cr;                  // parts, x faces i, i + 1, y faces, ring correction
  const T *fb, *cf, *af, *bf, *ayc, *byc, *ml, *mh;  // per column of the box (c0 on); faces: nc + 1
  T fA, fB, Ax, Bx, kv;
  T fbv, cfv;       // fb and cf where each is one value over the box row (fn reads these, not the rows)
  BoxRowFn<T> fn;   // the box row's loops (box_row<T, RZ, REG>)
  int64_t c0, nc, w_r;
  int box;                // its index in LayerArgs::boxes
  bool lo_edge, hi_edge;  // the box starts at column 0, ends at column ny
  bool first;             // the box's first row (its face r0 first)
  bool ok;                // planned (else the general path)
};

// a planned box row at one step: the y faces from q row i (q0; zero beyond the window), the ring
// correction, then x face i + 1 (from q rows i, i + 1) with the parts and P into out. RZ: the
// metric and the ring correction; REG: the x face's and the y faces' conductances one value each
// (f.fbv, f.cfv; the same products as with the rows). Same arithmetic as layer_x_face +
// layer_y_faces + layer_parts.
template <typename T, bool RZ, bool REG>
DL_LAYER_VW void box_row(const FastRow<T>& f, const LayerArgs<T>& la, int64_t ny, const T* q0, const T* qp, T* out,
                         LayerScratch<T>& S) {
  const int64_t nc = f.nc, c0 = f.c0;
  const int64_t w_r = RZ ? f.w_r : 0;
  T* __restrict w = f.wy;
  T* old = S.old.data();
  if (RZ && w_r) std::copy(w + nc - w_r, w + nc + 1, old);
  {
    const int64_t kb = f.lo_edge ? 1 : 0, ke = f.hi_edge ? nc : nc + 1;
    const T* __restrict af = f.af;
    const T* __restrict bf = f.bf;
    const T* __restrict cf = f.cf;
    if (kb) w[0] = af[0] * w[0] + bf[0] * (cf[0] * (q0[0] - T(0)));
    if (ke == nc) w[nc] = af[nc] * w[nc] + bf[nc] * (cf[nc] * (T(0) - q0[ny - 1]));
    const T* __restrict qf = q0 + c0;
    if constexpr (REG) {
      const T cv = f.cfv;
#pragma GCC ivdep
      for (int64_t k = kb; k < ke; ++k) w[k] = af[k] * w[k] + bf[k] * (cv * (qf[k] - qf[k - 1]));
    } else {
#pragma GCC ivdep
      for (int64_t k = kb; k < ke; ++k) w[k] = af[k] * w[k] + bf[k] * (cf[k] * (qf[k] - qf[k - 1]));
    }
  }
  if (RZ && w_r) {
    T* __restrict c = f.cr + (nc - w_r);
    const T* __restrict o = old;
#pragma GCC ivdep
    for (int64_t k = 0; k < w_r; ++k) {
      const int64_t kk = nc - w_r + k;
      const T sum = ((w[kk + 1] + w[kk]) + o[k + 1]) + o[k];
      c[k] = la.rad_decay[k] * c[k] + la.rad_drive[k] * sum;
    }
  }
  T* __restrict x = f.x;
  T* __restrict y = f.y;
  T* __restrict o = out + c0;
  T* __restrict fw = f.fw;
  const T* __restrict wlo = f.wlo;
  const T* __restrict wy = f.wy;
  const T* __restrict ayc = f.ayc;
  const T* __restrict byc = f.byc;
  const T* __restrict flo = q0 + c0;
  const T* __restrict fhi = qp + c0;
  const T* __restrict fb = f.fb;
  const T* __restrict ml = f.ml;
  const T* __restrict mh = f.mh;
  const T* __restrict cr = f.cr;
  const T fA = f.fA, fB = f.fB, Ax = f.Ax, Bx = f.Bx, kv = f.kv, fbv = f.fbv;
  auto cell = [&](int64_t k, T dy) {
    const T wh = fA * fw[k] + fB * ((REG ? fbv : fb[k]) * (fhi[k] - flo[k]));
    fw[k] = wh;
    const T xv = Ax * x[k] + Bx * (kv * (wh - wlo[k]));
    const T yv = ayc[k] * y[k] + byc[k] * (kv * dy);
    x[k] = xv;
    y[k] = yv;
    o[k] = xv + yv;
  };
  if constexpr (RZ) {
    const int64_t k_r = nc - w_r;
#pragma GCC ivdep
    for (int64_t k = 0; k < k_r; ++k) cell(k, mh[k] * wy[k + 1] - ml[k] * wy[k]);
#pragma GCC ivdep
    for (int64_t k = k_r; k < nc; ++k) cell(k, (mh[k] * wy[k + 1] - ml[k] * wy[k]) + cr[k]);
  } else {
#pragma GCC ivdep
    for (int64_t k = 0; k < nc; ++k) cell(k, wy[k + 1] - wy[k]);
  }
}

template <typename T>
struct FastRows {
  // the box rows of all rows in order (row i: [start[i], start[i + 1]), one per box of of_row[i]);
  // those not ok take the general path
  std::vector<FastRow<T>> rows;
  std::vector<int64_t> start;
  std::vector<T> ones;
  std::vector<std::unique_ptr<std::vector<T>>> values;  // rows of one value (ny + 1 each)
  bool any = false;
  // a row of ny + 1 copies of v (a coefficient held in a register: its value per column)
  const T* filled(T v) {
    for (const auto& r : values)
      if ((*r)[0] == v || ((*r)[0] != (*r)[0] && v != v)) return r->data();
    values.push_back(std::make_unique<std::vector<T>>(ones.size(), v));
    return values.back()->data();
  }
  // plan: the leapfrog's row plans (a row whose K it found one value has no K row pointer)
  FastRows(const LeapfrogArgs<T>& a, const LayerArgs<T>* la, const RowPlan<T>& plan) {
    if (!la || a.iso || la->iso_faces || a.keep.present()) return;
    // a metric held in registers (a grid one cell wide): the general path
    for (const Coef<T>* c : {&a.my_lo, &a.my_hi})
      if (c->present() && c->in_register()) return;
    const int64_t nx = a.nx, ny = a.ny;
    ones.assign(ny + 2, T(1));
    start.assign(nx + 1, 0);
    size_t total = 0;
    for (const auto& r : la->of_row) total += r.size();
    rows.reserve(total);
    for (int64_t i = 0; i < nx; ++i) {
      T kv;
      bool k_one;
      if (a.K.in_register()) {
        kv = a.K.value(i);
        k_one = true;
      } else {
        kv = a.K.row(i)[0];
        k_one = (i < int64_t(plan.ctx.size()) && plan.ctx[i].krow == nullptr) || all_equal(a.K.row(i), ny);
      }
      start[i] = int64_t(rows.size());
      for (int bi : la->of_row[i]) {
        const LayerBox<T>& b = la->boxes[bi];
        FastRow<T> f{};
        const int64_t c0 = b.c0, nc = b.c1 - b.c0, kr = i - b.r0;
        f.c0 = c0;
        f.nc = nc;
        f.w_r = b.cr ? la->w : 0;
        f.lo_edge = c0 == 0;
        f.hi_edge = b.c1 == ny;
        f.x = b.px + kr * nc;
        f.y = b.py + kr * nc;
        f.wlo = b.wx + kr * nc;
        f.fw = f.wlo + nc;
        f.wy = b.wy + kr * (nc + 1);
        f.cr = b.cr ? b.cr + kr * f.w_r - (nc - f.w_r) : nullptr;
        f.fb = (!a.bx.present() ? ones.data() : (a.bx.in_register() ? filled(a.bx.value(i + 1)) : a.bx.row(i + 1))) + c0;
        f.cf = (!a.by.present() ? ones.data() : (a.by.in_register() ? filled(a.by.value(i)) : a.by.row(i))) + c0;
        f.af = (la->ayf.present() ? la->ayf.row(0) : ones.data()) + c0;
        f.bf = (la->byf.present() ? la->byf.row(0) : ones.data()) + c0;
        f.ayc = (la->ayc.present() ? la->ayc.row(0) : ones.data()) + c0;
        f.byc = (la->byc.present() ? la->byc.row(0) : ones.data()) + c0;
        f.ml = a.my_lo.present() ? a.my_lo.row(i) + c0 : nullptr;
        f.mh = a.my_lo.present() ? a.my_hi.row(i) + c0 : nullptr;
        f.fA = la->axf.present() ? la->axf.at(i + 1, 0) : T(1);
        f.fB = la->bxf.present() ? la->bxf.at(i + 1, 0) : T(1);
        f.Ax = la->axc.present() ? la->axc.at(i, 0) : T(1);
        f.Bx = la->bxc.present() ? la->bxc.at(i, 0) : T(1);
        f.kv = kv;
        f.ok = k_one;
        f.first = i == b.r0;
        f.box = bi;
        // x face i + 1's conductances over the box (nc) and row i's inner y faces (those the
        // loop reads, not the window's end faces) one value each: held in registers
        const int64_t kb = f.lo_edge ? 1 : 0, ke = f.hi_edge ? nc : nc + 1;
        const bool reg = all_equal(f.fb, nc) && all_equal(f.cf + kb, ke - kb);
        f.fbv = f.fb[0];
        f.cfv = f.cf[kb];
        if (f.ml) f.fn = reg ? &box_row<T, true, true> : &box_row<T, true, false>;
        else f.fn = reg ? &box_row<T, false, true> : &box_row<T, false, false>;
        rows.push_back(f);
        any = any || k_one;
      }
    }
    start[nx] = int64_t(rows.size());
  }
};

// row i of box b at one step: its faces from the q rows of the previous step (qm, q0, qp: rows
// i - 1, i, i + 1, zero beyond the window), its parts, and P = px + py into the new row `out`
template <typename T>
void layer_row(const LeapfrogArgs<T>& a, const LayerArgs<T>& la, const IsoWeights<T>& iw, const LayerBox<T>& b,
               int64_t i, const T* qm, const T* q0, const T* qp, T* out, LayerScratch<T>& S) {
  const int64_t ny = a.ny, c0 = b.c0, nc = b.c1 - b.c0, kr = i - b.r0;
  // the common case (standard stencil, no keep, K one value on the row: a layer in one material):
  // the x face i + 1 is updated in the loop of the parts, and the arrays of ones and of K are not
  // read (the same arithmetic: keep = 1 multiplies exactly, K's row holds the one value)
  T kv = T(0);
  const bool fast = !a.iso && !a.keep.present() && S.k_uniform(a.K, i, a.nx, ny, &kv);
  if (i == b.r0) layer_x_face(a, la, iw, b, 0, i, qm, q0, S);
  if (!fast) layer_x_face(a, la, iw, b, kr + 1, i + 1, q0, qp, S);
  if (a.iso && !la.iso_faces) {  // the y faces from P = q0 filtered across them (am, ap = 0 at the first / last row)
    T* __restrict P = S.P.data();
    const T am = i > 0 ? T(1) : T(0), ap = i + 1 < a.nx ? T(1) : T(0);
    constexpr T w12 = T(1.0 / 12.0);
    const int64_t j0 = std::max<int64_t>(c0 - 1, 0), j1 = std::min<int64_t>(b.c1 + 1, ny);
    for (int64_t j = j0; j < j1; ++j) P[j] = q0[j] + (ap * (qp[j] - q0[j]) - am * (q0[j] - qm[j])) * w12;
    layer_y_faces(a, la, b, kr, i, P, qm, qp, S);
  } else {
    layer_y_faces(a, la, b, kr, i, q0, qm, qp, S);
  }
  T* __restrict x = b.px + kr * nc;
  T* __restrict y = b.py + kr * nc;
  const T* __restrict wlo = b.wx + kr * nc;
  const T* __restrict whi = wlo + nc;
  const T* __restrict wy = b.wy + kr * (nc + 1);
  const T Ax = la.axc.present() ? la.axc.at(i, 0) : T(1), Bx = la.bxc.present() ? la.bxc.at(i, 0) : T(1);
  const T* __restrict ayc = (la.ayc.present() ? la.ayc.row(0) : S.ones.data()) + c0;
  const T* __restrict byc = (la.byc.present() ? la.byc.row(0) : S.ones.data()) + c0;
  T* __restrict o = out + c0;
  const T* __restrict ml = a.my_lo.present() ? S.ml.get(a.my_lo, i, ny) + c0 : nullptr;
  const T* __restrict mh = a.my_lo.present() ? S.mh.get(a.my_hi, i, ny) + c0 : nullptr;
  const int64_t w_r = b.cr ? la.w : 0;
  const T* cr = b.cr ? b.cr + kr * w_r - (nc - w_r) : nullptr;
  if (fast) {
    XFace<T> xf;  // layer_x_face's plain form for face i + 1
    xf.w = b.wx + (kr + 1) * nc;
    xf.lo = q0 + c0;
    xf.hi = qp + c0;
    xf.b = (a.bx.present() ? S.bxl.get(a.bx, i + 1, ny) : S.ones.data()) + c0;
    xf.A = la.axf.present() ? la.axf.at(i + 1, 0) : T(1);
    xf.B = la.bxf.present() ? la.bxf.at(i + 1, 0) : T(1);
    if (ml) layer_parts<T, true>(x, y, o, wlo, whi, wy, ayc, byc, Ax, Bx, &xf, nullptr, kv, ml, mh, cr, nc, w_r);
    else layer_parts<T, false>(x, y, o, wlo, whi, wy, ayc, byc, Ax, Bx, &xf, nullptr, kv, ml, mh, cr, nc, w_r);
    return;
  }
  const T* __restrict kk = S.k.get(a.K, i, ny) + c0;
  const T* __restrict kp = (a.keep.present() ? S.keep.get(a.keep, i, ny) : S.ones.data()) + c0;  // 1 x is x
  if (ml) layer_parts<T, true>(x, y, o, wlo, whi, wy, ayc, byc, Ax, Bx, kk, kp, T(0), ml, mh, cr, nc, w_r);
  else layer_parts<T, false>(x, y, o, wlo, whi, wy, ayc, byc, Ax, Bx, kk, kp, T(0), ml, mh, cr, nc, w_r);
}

}  // namespace dl
