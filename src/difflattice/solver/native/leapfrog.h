// the leapfrog over a block of steps (temporal blocking, threads; PML layers, air absorption)
// (part of the native kernels: included by lattice.cc, one translation unit)
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <optional>
#include <vector>

#include "layers.h"
#include "threads.h"

namespace dl {

// RELAX: air absorption (a compile-time flag: the lossless instantiation has none of its code)
template <typename T, bool RELAX>
bool leapfrog_steps(const LeapfrogArgs<T>& a) {
  const int64_t nx = a.nx, ny = a.ny;
  const int levels = std::max(1, a.levels);
  const CellPlan<T> cplan(a.cells, nx);
  const bool stats = a.cells.p_max || a.cells.p_sq || a.cells.arrival;
  const bool adj = a.combine == kAdj;
  constexpr bool relax = RELAX;
  const bool extras = !adj && (a.qs.present() || a.keep.present() || a.sponge.present() || a.eta != 0.0 || relax);
  // the adjoint with a scalar K is the forward step: L(K a) = K L(a)
  const bool adj_scalar = adj && a.K.in_register();
  const int cmb = adj_scalar ? kFwd : (adj ? kAdj : (extras ? kD : kFwd));
  const bool qbuf = (adj && !adj_scalar) || a.qs.present() || a.eta != 0.0 || relax;  // q rows computed
  RowPlan<T> plan;
  if (!(a.iso ? plan_iso(a, cmb, plan) : plan_rows(a, cmb, plan))) return false;
  const T eta1 = T(1.0 + a.eta), eta = T(a.eta);
  T* buf[2] = {a.p, a.pp};  // step L lives in buf[L % 2] (step 0 = P(t) in buf[0])
  const LayerArgs<T>* la = a.layers;
  const IsoWeights<T> iw(la && a.iso ? ny : 0, a.my_lo.present());
  const FastRows<T> fr(a, la, plan);  // the common case's box rows, planned once

  // q of row i from step L - 1 (p_) and step L - 2 (pp_), before step L overwrites row i
  auto q_of = [&](int64_t i, T* dst, const T* p_, const T* pp_) {
    const T* pr = p_ + i * ny;
    if (adj) {
      if (a.K.in_register()) {
        const T k = a.K.value(i);
        for (int64_t j = 0; j < ny; ++j) dst[j] = k * pr[j];
      } else {
        const T* kr = a.K.row(i);
        for (int64_t j = 0; j < ny; ++j) dst[j] = kr[j] * pr[j];
      }
      return;
    }
    if (a.eta != 0.0) {
      const T* ppr = pp_ + i * ny;
      for (int64_t j = 0; j < ny; ++j) dst[j] = eta1 * pr[j] - eta * ppr[j];
    } else {
      for (int64_t j = 0; j < ny; ++j) dst[j] = pr[j];
    }
    if constexpr (relax) {  // stepper._relaxed_operand, in its order
      const T* ppr = pp_ + i * ny;
      const T* q0r = a.rq[0] + i * ny;
      const T* q1r = a.rq[1] + i * ny;
      const T re = a.r_eta, e0 = a.r_eps[0], e1 = a.r_eps[1];
#pragma GCC ivdep
      for (int64_t j = 0; j < ny; ++j) dst[j] = ((dst[j] + re * (pr[j] - ppr[j])) + e0 * q0r[j]) + e1 * q1r[j];
    }
    if (a.qs.present()) {
      if (a.qs.in_register()) {
        const T s = a.qs.value(i);
        for (int64_t j = 0; j < ny; ++j) dst[j] = s * dst[j];
      } else {
        const T* sr = a.qs.row(i);
        for (int64_t j = 0; j < ny; ++j) dst[j] = sr[j] * dst[j];
      }
    }
  };
  const std::vector<T> zero(ny, T(0));

  struct Level {  // per-step scratch of one thread
    std::vector<T> ring, d;
    T* q[3] = {nullptr, nullptr, nullptr};  // q rows i - 1, i, i + 1 (qbuf)
  };
  auto make_worker = [&](int) {
    std::vector<Level> lv(levels);
    for (auto& l : lv) {
      if (qbuf) l.ring.assign(3 * ny, T(0));
      if (extras) l.d.assign(ny, T(0));
    }
    std::optional<LayerScratch<T>> ls;
    if (la) ls.emplace(ny, la->w);
    return [&, lv = std::move(lv), ls = std::move(ls)](int l, int64_t L, int64_t i) mutable {
      Level& S = lv[l];
      const T* p = buf[(L - 1) & 1];  // step L - 1
      T* pp = buf[L & 1];             // step L - 2, overwritten by step L
      RowIO<T> c;
      if (qbuf) {
        if (i == 0) {
          S.q[0] = S.ring.data();
          S.q[1] = S.ring.data() + ny;
          S.q[2] = S.ring.data() + 2 * ny;
          std::fill(S.q[0], S.q[0] + ny, T(0));
          q_of(0, S.q[1], p, pp);
        } else {
          std::swap(S.q[0], S.q[1]);
          std::swap(S.q[1], S.q[2]);
        }
        if (i + 1 < nx) q_of(i + 1, S.q[2], p, pp);
        else std::fill(S.q[2], S.q[2] + ny, T(0));
        c.qm = S.q[0];
        c.q0 = S.q[1];
        c.qp = S.q[2];
      } else {
        c.q0 = p + i * ny;
        c.qm = i > 0 ? c.q0 - ny : zero.data();
        c.qp = i + 1 < nx ? c.q0 + ny : zero.data();
      }
      T* out = pp + i * ny;
      const T* p0 = p + i * ny;
      c.p0 = p0;
      c.pp0 = out;
      if (la && la->whole_row[i]) {
        // a row of layer cells only: the boxes write it
      } else if (!extras) {
        c.out = out;
        plan.fn[i](plan.ctx[i], c, ny);
      } else {
        T* d = S.d.data();
        c.out = d;
        plan.fn[i](plan.ctx[i], c, ny);
        if (a.sponge.present()) {
          for (int64_t j = 0; j < ny; ++j) {
            const T sv = a.sponge.at(i, j);
            out[j] = ((T(2) * p0[j] - (T(1) - sv) * out[j]) + d[j]) / (T(1) + sv);
          }
        } else {
          for (int64_t j = 0; j < ny; ++j) out[j] = (T(2) * p0[j] - out[j]) + d[j];
        }
        if (a.keep.present()) {
          if (a.keep.in_register()) {
            const T kv = a.keep.value(i);
            for (int64_t j = 0; j < ny; ++j) out[j] = kv * out[j];
          } else {
            const T* kr = a.keep.row(i);
            for (int64_t j = 0; j < ny; ++j) out[j] = kr[j] * out[j];
          }
        }
      }
      if (la)  // the layer's cells of the row: the split-field form replaces the leapfrog's values
        if (fr.any) {
          for (const FastRow<T>* f = fr.rows.data() + fr.start[i], *e = fr.rows.data() + fr.start[i + 1]; f != e; ++f) {
            const LayerBox<T>& b = la->boxes[f->box];
            if (f->ok) {
              if (f->first) layer_x_face(a, *la, iw, b, 0, i, c.qm, c.q0, *ls);
              f->fn(*f, *la, ny, c.q0, c.qp, out, *ls);
            } else {
              layer_row(a, *la, iw, b, i, c.qm, c.q0, c.qp, out, *ls);
            }
          }
        } else {
          for (int bi : la->of_row[i]) layer_row(a, *la, iw, la->boxes[bi], i, c.qm, c.q0, c.qp, out, *ls);
        }
      if (cplan.busy[i]) leapfrog_cells(a.cells, cplan, i, L - 1, pp);
      if constexpr (relax) {  // stepper._relaxed_memory: step L - 1's q rows of row i are read (q ring)
        T* q0r = a.rq[0] + i * ny;
        T* q1r = a.rq[1] + i * ny;
        const T a0 = a.r_a[0], a1 = a.r_a[1], g0 = a.r_g[0], g1 = a.r_g[1];
#pragma GCC ivdep
        for (int64_t j = 0; j < ny; ++j) {
          const T dp = out[j] - p0[j];
          q0r[j] = a0 * q0r[j] + g0 * dp;
          q1r[j] = a1 * q1r[j] + g1 * dp;
        }
      }
      if (stats) row_stats(a.cells, i, L - 1, out);
    };
  };
  // an odd number of steps leaves the latest field in the P(t-1) buffer: swap the contents
  auto finish = [&](int t, int nt) {
    if (a.n_steps % 2 == 0) return;
    const int64_t r0 = nx * t / nt, r1 = nx * (t + 1) / nt;
    for (int64_t i = r0; i < r1; ++i) std::swap_ranges(a.p + i * ny, a.p + (i + 1) * ny, a.pp + i * ny);
  };
  if (a.bands && !qbuf && !la) bands(nx, a.n_steps, a.n_threads, make_worker, finish);
  else pipeline(nx, ny, a.n_steps, a.n_threads, levels, make_worker, finish);
  return true;
}

template <typename T>
bool leapfrog(const LeapfrogArgs<T>& a) {
  if (a.rq[0] != nullptr && a.combine != kAdj) return leapfrog_steps<T, true>(a);
  return leapfrog_steps<T, false>(a);
}

}  // namespace dl
