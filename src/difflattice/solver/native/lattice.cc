// difflattice native CPU kernels, called from JAX as XLA FFI custom calls
// (difflattice.solver.native). Two time steppers of difflattice.solver.stepper, advanced over a
// block of steps per call:
//
// - `difflattice_leapfrog`: P(t+1) = 2 P(t) - P(t-1) + K L(q), L the flux stencil of
//   difflattice.lattice.operators, with the optional sponge, soft-cell factor (`keep`), q = c^2 P
//   (`q_scale`) and viscous (`eta`) terms; `combine = 2` runs the adjoint step instead.
// - `difflattice_layered`: the leapfrog with PML layers: the split-field form (face fluxes wx, wy;
//   pressure parts px, py) on the layer's boxes only, the leapfrog's arithmetic everywhere else.
//
// Both run the standard 5-point stencil, and the isotropic 9-point one (attribute `stencil` = 1)
// on uniform faces (air: the window's 0/1 masks and the rz metric; `row_iso`, `face_x_iso`).
//
// Both carry humid air's absorption (lattice.coefficients.AirRelaxation) when given its optional
// arguments: the operand adds eta (P - P(n-1)) + eps_O Q_O + eps_N Q_N, and after the sources
// Q_i = a_i Q_i + g_i (P(n+1) - P(n)) row by row, in place (a compile-time flag: the lossless
// instantiations have none of it).
//
// Both apply the sources, record probes, phasors and whole-field statistics inside the loop, in
// the order of the JAX stepper. Coefficient arrays are inputs of any layout that broadcasts to
// the grid (a scalar, one value per row, one vector for all rows, or a full array), so a lattice
// with metric coefficients (axisymmetric) runs the same code.
//
// Speed: temporal blocking (each thread advances several steps per sweep over the rows, one row
// apart) and a pipeline of threads (thread t takes the steps after thread t - 1's, one row
// behind it), so rows are loaded from memory once per block of steps and all cores work without
// a barrier per step. Results agree with the JAX reference to rounding (the stencil sums the
// neighbours first where faces have unit conductance; XLA contracts a * b + c into FMAs, so this
// file is compiled with -ffp-contract=fast as well).
#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <type_traits>
#include <vector>

#include <unistd.h>  // getpid
#if defined(__x86_64__) || defined(_M_X64)
#include <immintrin.h>
#define DL_PAUSE() _mm_pause()
#else
#define DL_PAUSE() ((void)0)
#endif

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace dl {

// ----------------------------------------------------------------------------------------------
// threads

class SpinBarrier {
 public:
  explicit SpinBarrier(int n) : n_(n), count_(n), gen_(0) {}
  void wait() {
    if (n_ == 1) return;
    const int g = gen_.load(std::memory_order_acquire);
    if (count_.fetch_sub(1, std::memory_order_acq_rel) == 1) {
      count_.store(n_, std::memory_order_relaxed);
      gen_.fetch_add(1, std::memory_order_release);
      return;
    }
    int spins = 0;
    while (gen_.load(std::memory_order_acquire) == g) {
      if (++spins < 4000) {
        DL_PAUSE();
      } else {
        std::this_thread::yield();  // an oversubscribed machine: let the other thread run
      }
    }
  }

 private:
  const int n_;
  std::atomic<int> count_;
  std::atomic<int> gen_;
};

// XLA's CPU code flushes denormals to zero (FTZ and DAZ); the kernels' threads do the same, so
// both agree on tiny values and no thread slows down on denormal arithmetic
class FlushDenormals {
 public:
#if defined(__x86_64__) || defined(_M_X64)
  FlushDenormals() : saved_(_mm_getcsr()) { _mm_setcsr(saved_ | 0x8040); }
  ~FlushDenormals() { _mm_setcsr(saved_); }

 private:
  unsigned int saved_;
#endif
};

// Worker threads kept between calls. A thread created per call starts beside its creator and is
// moved to the idle core only later: measured, 840x630 x 1000 steps on two threads in calls of 128
// steps ran at 4800-5900 MLUPS with threads created per call, 7200-8400 in one call. One job at a
// time: a call that finds the pool busy (another XLA thread in a kernel) creates its own threads.
class Pool {
 public:
  using Fn = void (*)(void*, int);

  static Pool& get() {  // never destroyed: its threads block in a wait at exit
    static Pool* pool = new Pool();
    return *pool;
  }

  // run fn(ctx, t) for t = 1 .. n - 1 on the workers and fn(ctx, 0) here; false (nothing run)
  // when the pool is busy or this is a forked child (whose workers do not exist)
  bool run(int n, Fn fn, void* ctx) {
    std::unique_lock<std::mutex> busy(busy_, std::try_to_lock);
    if (!busy.owns_lock() || getpid() != pid_) return false;
    {
      std::lock_guard<std::mutex> lk(m_);
      while (int(workers_.size()) < n - 1) {
        const int t = int(workers_.size()) + 1;
        workers_.emplace_back([this, t] { loop(t); });
        workers_.back().detach();
      }
      fn_ = fn;
      ctx_ = ctx;
      n_ = n;
      pending_ = n - 1;
      ++gen_;
    }
    cv_.notify_all();
    fn(ctx, 0);
    std::unique_lock<std::mutex> lk(m_);
    done_.wait(lk, [this] { return pending_ == 0; });
    return true;
  }

 private:
  Pool() : pid_(getpid()) {}

  void loop(int t) {
    uint64_t seen = 0;
    for (;;) {
      Fn fn;
      void* ctx;
      {
        std::unique_lock<std::mutex> lk(m_);
        cv_.wait(lk, [&] { return gen_ != seen && t < n_; });
        seen = gen_;
        fn = fn_;
        ctx = ctx_;
      }
      fn(ctx, t);
      std::lock_guard<std::mutex> lk(m_);
      if (--pending_ == 0) done_.notify_one();
    }
  }

  const pid_t pid_;
  std::mutex busy_, m_;
  std::condition_variable cv_, done_;
  std::vector<std::thread> workers_;
  Fn fn_ = nullptr;
  void* ctx_ = nullptr;
  int n_ = 0, pending_ = 0;
  uint64_t gen_ = 0;
};

template <typename F>
void parallel(int n_threads, F&& body) {
  FlushDenormals ftz;
  if (n_threads <= 1) {
    body(0);
    return;
  }
  using B = std::remove_reference_t<F>;
  auto call = [](void* ctx, int t) {
    FlushDenormals ftz_thread;
    (*static_cast<B*>(ctx))(t);
  };
  if (Pool::get().run(n_threads, call, const_cast<void*>(static_cast<const void*>(&body)))) return;
  std::vector<std::thread> pool;
  pool.reserve(n_threads - 1);
  for (int t = 1; t < n_threads; ++t)
    pool.emplace_back([&body, t] {
      FlushDenormals ftz_thread;
      body(t);
    });
  body(0);
  for (auto& th : pool) th.join();
}

// The pipeline of steps: a block of n_threads * levels steps; thread t advances steps
// first_t .. first_t + mine_t - 1 in one sweep over the rows (step first_t + l at row m - l at
// sweep position m), its first step waiting for the previous thread's last step to have finished
// the row below. `make_worker(t)` returns a callable row(l, L, i): row i of step L (1-based in the
// call) using the scratch of level l; `finish(t)` runs after the last block.
struct alignas(64) Progress {  // rows finished by a thread's last step (one cache line each)
  std::atomic<int64_t> rows{0};
};

template <typename MakeWorker, typename Finish>
void pipeline(int64_t nx, int64_t ny, int64_t n_steps, int n_threads, int levels, MakeWorker&& make_worker,
              Finish&& finish) {
  const int nt = std::max(1, n_threads);
  levels = std::max(1, levels);
  std::vector<Progress> progress(nt);
  // progress is published every `stride` rows (~16 KB of a field), so the counter's cache line
  // moves between cores once per stride rather than once per row
  const int64_t stride = std::max<int64_t>(1, 4096 / std::max<int64_t>(1, ny));
  SpinBarrier barrier(nt);
  parallel(nt, [&](int t) {
    auto row = make_worker(t);
    for (int64_t s0 = 0; s0 < n_steps; s0 += int64_t(nt) * levels) {
      const int64_t n_block = std::min<int64_t>(int64_t(nt) * levels, n_steps - s0);
      const int64_t base = n_block / nt, extra = n_block % nt;
      const int64_t first = s0 + 1 + t * base + std::min<int64_t>(t, extra);
      const int64_t mine = base + (t < extra ? 1 : 0);
      progress[t].rows.store(0, std::memory_order_relaxed);
      barrier.wait();
      if (mine > 0) {
        const bool wait_prev = t > 0 && first - 1 > s0;  // step first - 1 is another thread's
        int64_t seen = 0;  // the previous thread's progress as last read
        for (int64_t m = 0; m < nx + mine - 1; ++m) {
          for (int64_t l = 0; l < mine; ++l) {
            const int64_t i = m - l;
            if (i < 0 || i >= nx) continue;
            if (l == 0 && wait_prev) {
              const int64_t need = std::min<int64_t>(i + 2, nx);
              int spins = 0;
              while (seen < need) {
                seen = progress[t - 1].rows.load(std::memory_order_acquire);
                if (seen >= need) break;
                if (++spins < 4000) DL_PAUSE();
                else std::this_thread::yield();
              }
            }
            row(int(l), first + l, i);
            if (l == mine - 1 && ((i + 1) % stride == 0 || i + 1 == nx))
              progress[t].rows.store(i + 1, std::memory_order_release);
          }
        }
      } else {
        progress[t].rows.store(nx, std::memory_order_release);
      }
      barrier.wait();
    }
    finish(t, nt);
  });
}

// Row bands, one step at a time (on request, `bands`): thread t updates rows
// [nx t / n, nx (t + 1) / n) of every step, with a barrier per step: numba's parallel scheme, kept
// for comparison. It keeps each core on its own rows but stalls both threads whenever one is
// disturbed (quiet 2-vCPU EPYC, 840x630: median 3618 MLUPS against the pipeline's 8621).
template <typename MakeWorker, typename Finish>
void bands(int64_t nx, int64_t n_steps, int n_threads, MakeWorker&& make_worker, Finish&& finish) {
  const int nt = std::max(1, n_threads);
  SpinBarrier barrier(nt);
  parallel(nt, [&](int t) {
    auto row = make_worker(t);
    const int64_t r0 = nx * t / nt, r1 = nx * (t + 1) / nt;
    for (int64_t s = 1; s <= n_steps; ++s) {
      for (int64_t i = r0; i < r1; ++i) row(0, s, i);
      barrier.wait();
    }
    finish(t, nt);
  });
}

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

// row i of step s (0-based in the call) of the leapfrog, on the new field nw
template <typename T>
void leapfrog_cells(const CellOps<T>& c, const CellPlan<T>& pl, int64_t i, int64_t s, T* nw) {
  const int64_t ny = c.ny;
  for (int64_t u = pl.src.start[i]; u < pl.src.start[i + 1]; ++u) {
    const int64_t k = pl.src.item[u];
    const int64_t at = i * ny + c.src_cells[2 * k + 1];
    const T v = c.src_vals[s * c.n_src + k];
    if (c.src_hard[k]) nw[at] = v;
    else nw[at] = nw[at] + v;
  }
  for (int64_t u = pl.rec.start[i]; u < pl.rec.start[i + 1]; ++u) {
    const int64_t k = pl.rec.item[u];
    c.rec_out[s * c.n_rec + k] = nw[i * ny + c.rec_cells[2 * k + 1]];
  }
  for (int64_t u = pl.zer.start[i]; u < pl.zer.start[i + 1]; ++u) {
    const int64_t k = pl.zer.item[u];
    nw[i * ny + c.zero_cells[2 * k + 1]] = T(0);
  }
  if (pl.pha.start[i] != pl.pha.start[i + 1]) {
    const T cs = c.ph_cos[s], sn = c.ph_sin[s];
    for (int64_t u = pl.pha.start[i]; u < pl.pha.start[i + 1]; ++u) {
      const int64_t k = pl.pha.item[u];
      const T v = nw[i * ny + c.ph_cells[2 * k + 1]];
      c.ph_re[k] = c.ph_re[k] + v * cs;
      c.ph_im[k] = c.ph_im[k] + v * sn;
    }
  }
}

// statistics of one row of the new field p (ny values), at step s
template <typename T>
void row_stats(const CellOps<T>& c, int64_t i, int64_t s, const T* p) {
  const int64_t ny = c.ny;
  if (c.p_max) {
    T* m = c.p_max + i * ny;
    for (int64_t j = 0; j < ny; ++j) {
      const T v = std::abs(p[j]);
      m[j] = (v > m[j] || v != v) ? v : m[j];  // jnp.maximum: NaN wins
    }
  }
  if (c.p_sq) {
    T* q = c.p_sq + i * ny;
    for (int64_t j = 0; j < ny; ++j) q[j] = q[j] + p[j] * p[j];
  }
  if (c.arrival) {
    int32_t* a = c.arrival + i * ny;
    const int32_t n_next = int32_t(c.n0 + s + 1);
    for (int64_t j = 0; j < ny; ++j)
      if (a[j] < 0 && std::abs(p[j]) > c.threshold) a[j] = n_next;
  }
}

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
// factors sum to 2 inside the row (A_(j+1) + A_j = 2 V_j), so the update keeps the unit stencil's
// form with two multiplies: qn m_hi + qs m_lo - 2 q
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
  const T k = c.k, c0 = c.c0, bxl = c.bxlo, bxh = c.bxhi, byv = c.by;
  if (ny == 1) {
    out[0] = edge_cell<T, BX, KREG, CMB>(c, io, 0, T(0), T(0), c.by_first_lo, c.by_last_hi);
    return;
  }
  const T first = edge_cell<T, BX, KREG, CMB>(c, io, 0, T(0), q0[1], c.by_first_lo, c.by_first_hi);
  const T last = edge_cell<T, BX, KREG, CMB>(c, io, ny - 1, q0[ny - 2], T(0), c.by_last_lo, c.by_last_hi);
  constexpr bool UNIT = BX == kUnit && BY == kUnit;
  constexpr bool RING = BX == kUnit && BY == kMetric;
#pragma GCC ivdep
  for (int64_t j = 1; j < ny - 1; ++j) {
    const T q = q0[j], e = qp[j], w = qm[j], n = q0[j + 1], s = q0[j - 1];
    T l, sum;
    if constexpr (UNIT) {
      sum = ((e + w) + n) + s;
      l = sum - T(4) * q;
    } else if constexpr (RING) {
      sum = ((e + w) + cyh[j] * n) + cyl[j] * s;
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
    plan.cy_lo.assign(rows * ny, T(0));
    plan.cy_hi.assign(rows * ny, T(0));
    for (int64_t i = 0; i < rows; ++i)
      for (int64_t j = 0; j < ny; ++j) {
        const T ml = a.my_lo.at(i, j), mh = a.my_hi.at(i, j);
        plan.cy_lo[i * ny + j] = by.present() ? ml * by.at(i, j) : ml;
        plan.cy_hi[i * ny + j] = by.present() ? mh * by.at(i, j + 1) : mh;
      }
  }
  // the ring form: the metric's interior factors sum to 2 (to rounding) in one shared row
  bool ring_form = metric && !cy_rows && cmb == kFwd && ny > 2;
  for (int64_t j = 1; ring_form && j < ny - 1; ++j) {
    const T d = plan.cy_lo[j] + plan.cy_hi[j] - T(2);
    ring_form = (d < T(0) ? -d : d) <= T(8) * std::numeric_limits<T>::epsilon();
  }
  plan.fn.resize(nx);
  plan.ctx.resize(nx);
  // A row whose coefficients are one value (a layered medium, the rows that miss an obstacle) runs
  // the kernel of register coefficients: the arrays are not streamed for it
  auto uniform = [](const T* r, int64_t n) {
    for (int64_t j = 1; j < n; ++j)
      if (!(r[j] == r[0])) return false;
    return true;
  };
  for (int64_t i = 0; i < nx; ++i) {
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
    if (bxm == kVec && bym != kVec) return false;  // (by was materialised above)
    if (ring_form && bxm == kUnit && bym == kVec) bym = kMetric;
    RowFn<T> f = cmb == kAdj ? pick_row<T, kAdj>(bxm, bym, kreg)
                             : (cmb == kD ? pick_row<T, kD>(bxm, bym, kreg) : pick_row<T, kFwd>(bxm, bym, kreg));
    if (!f) return false;
    plan.fn[i] = f;
  }
  return true;
}

// per-thread scratch of the layer rows
template <typename T>
struct LayerScratch {
  RowBuf<T> k, bxl, bxh, by, keep, ml, mh;
  std::vector<T> ones, old, d, P, e;
  explicit LayerScratch(int64_t ny, int64_t w)
      : ones(ny + 2, T(1)), old(w + 1, T(0)), d(ny + 2, T(0)), P(ny + 2, T(0)), e(ny + 1, T(0)) {}
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
void layer_x_face(const LeapfrogArgs<T>& a, const LayerArgs<T>& la, const IsoWeights<T>& iw, const LayerBox<T>& b,
                  int64_t kf, int64_t f, const T* __restrict lo, const T* __restrict hi, LayerScratch<T>& S) {
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
void layer_y_faces(const LeapfrogArgs<T>& a, const LayerArgs<T>& la, const LayerBox<T>& b, int64_t kr, int64_t i,
                   const T* __restrict q, const T* qm, const T* qp, LayerScratch<T>& S) {
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
    T* c = b.cr + kr * w_r;
    for (int64_t k = 0; k < w_r; ++k) {
      const int64_t kk = nc - w_r + k;  // the box's face of ring ny - w + k
      const T sum = ((w[kk + 1] + w[kk]) + old[k + 1]) + old[k];
      c[k] = la.rad_decay[k] * c[k] + la.rad_drive[k] * sum;
    }
  }
}

// row i of box b at one step: its faces from the q rows of the previous step (qm, q0, qp: rows
// i - 1, i, i + 1, zero beyond the window), its parts, and P = px + py into the new row `out`
template <typename T>
void layer_row(const LeapfrogArgs<T>& a, const LayerArgs<T>& la, const IsoWeights<T>& iw, const LayerBox<T>& b,
               int64_t i, const T* qm, const T* q0, const T* qp, T* out, LayerScratch<T>& S) {
  const int64_t ny = a.ny, c0 = b.c0, nc = b.c1 - b.c0, kr = i - b.r0;
  if (i == b.r0) layer_x_face(a, la, iw, b, 0, i, qm, q0, S);
  layer_x_face(a, la, iw, b, kr + 1, i + 1, q0, qp, S);
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
  const T* __restrict kk = S.k.get(a.K, i, ny) + c0;
  const T Ax = la.axc.present() ? la.axc.at(i, 0) : T(1), Bx = la.bxc.present() ? la.bxc.at(i, 0) : T(1);
  const T* __restrict ayc = (la.ayc.present() ? la.ayc.row(0) : S.ones.data()) + c0;
  const T* __restrict byc = (la.byc.present() ? la.byc.row(0) : S.ones.data()) + c0;
  const T* __restrict kp = (a.keep.present() ? S.keep.get(a.keep, i, ny) : S.ones.data()) + c0;  // 1 x is x
  T* __restrict o = out + c0;
  // one pass: px, py (keep), P = px + py
  if (a.my_lo.present()) {  // rz: (m_hi w_(j+1) - m_lo w_j) (+ C on the ring columns)
    const T* __restrict ml = S.ml.get(a.my_lo, i, ny) + c0;
    const T* __restrict mh = S.mh.get(a.my_hi, i, ny) + c0;
    const int64_t w_r = b.cr ? la.w : 0, k_r = nc - w_r;
#pragma GCC ivdep
    for (int64_t k = 0; k < k_r; ++k) {
      const T xv = kp[k] * (Ax * x[k] + Bx * (kk[k] * (whi[k] - wlo[k])));
      const T yv = kp[k] * (ayc[k] * y[k] + byc[k] * (kk[k] * (mh[k] * wy[k + 1] - ml[k] * wy[k])));
      x[k] = xv;
      y[k] = yv;
      o[k] = xv + yv;
    }
    const T* c = b.cr ? b.cr + kr * w_r - k_r : nullptr;
    for (int64_t k = k_r; k < nc; ++k) {
      const T xv = kp[k] * (Ax * x[k] + Bx * (kk[k] * (whi[k] - wlo[k])));
      const T yv = kp[k] * (ayc[k] * y[k] + byc[k] * (kk[k] * ((mh[k] * wy[k + 1] - ml[k] * wy[k]) + c[k])));
      x[k] = xv;
      y[k] = yv;
      o[k] = xv + yv;
    }
  } else {
#pragma GCC ivdep
    for (int64_t k = 0; k < nc; ++k) {
      const T xv = kp[k] * (Ax * x[k] + Bx * (kk[k] * (whi[k] - wlo[k])));
      const T yv = kp[k] * (ayc[k] * y[k] + byc[k] * (kk[k] * (wy[k + 1] - wy[k])));
      x[k] = xv;
      y[k] = yv;
      o[k] = xv + yv;
    }
  }
}

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
        for (int bi : la->of_row[i]) layer_row(a, *la, iw, la->boxes[bi], i, c.qm, c.q0, c.qp, out, *ls);
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

// ------------------------------------------------------------------------------------------------
// FFI binding

namespace {

template <typename T>
T* out_from(ffi::Result<ffi::AnyBuffer>& r, const ffi::AnyBuffer& in) {
  T* dst = reinterpret_cast<T*>(r->untyped_data());
  if (in.element_count() && dst != in.untyped_data()) std::memcpy(dst, in.untyped_data(), in.size_bytes());
  return in.element_count() ? dst : nullptr;
}

bool inside(const ffi::AnyBuffer& cells, int64_t nx, int64_t ny) {
  const int32_t* c = reinterpret_cast<const int32_t*>(cells.untyped_data());
  const int64_t n = int64_t(cells.element_count() / 2);
  for (int64_t k = 0; k < n; ++k)
    if (c[2 * k] < 0 || c[2 * k] >= nx || c[2 * k + 1] < 0 || c[2 * k + 1] >= ny) return false;
  return true;
}

const char* kOutside = "difflattice: a source or sensor cell lies outside the grid";

template <typename T>
void bind_cells(dl::CellOps<T>& c, int64_t ny, const ffi::AnyBuffer& src_cells, const ffi::AnyBuffer& src_hard,
                const ffi::AnyBuffer& src_vals, const ffi::AnyBuffer& rec_cells, ffi::Result<ffi::AnyBuffer>& rec,
                const ffi::AnyBuffer& ph_cells, const ffi::AnyBuffer& ph_cos, const ffi::AnyBuffer& ph_sin,
                T* ph_re, T* ph_im, T* p_max, T* p_sq, int32_t* arrival, const ffi::AnyBuffer& n0,
                double threshold) {
  c.ny = ny;
  c.src_cells = reinterpret_cast<const int32_t*>(src_cells.untyped_data());
  c.src_hard = reinterpret_cast<const int32_t*>(src_hard.untyped_data());
  c.src_vals = reinterpret_cast<const T*>(src_vals.untyped_data());
  c.n_src = int64_t(src_cells.element_count() / 2);
  c.rec_cells = reinterpret_cast<const int32_t*>(rec_cells.untyped_data());
  c.n_rec = int64_t(rec_cells.element_count() / 2);
  c.rec_out = reinterpret_cast<T*>(rec->untyped_data());
  c.ph_cells = reinterpret_cast<const int32_t*>(ph_cells.untyped_data());
  c.n_ph = int64_t(ph_cells.element_count() / 2);
  c.ph_cos = reinterpret_cast<const T*>(ph_cos.untyped_data());
  c.ph_sin = reinterpret_cast<const T*>(ph_sin.untyped_data());
  c.ph_re = ph_re;
  c.ph_im = ph_im;
  c.p_max = p_max;
  c.p_sq = p_sq;
  c.arrival = arrival;
  c.threshold = T(threshold);
  c.n0 = *reinterpret_cast<const int32_t*>(n0.untyped_data());
}

// air absorption's inputs (both kernels), optional arguments and results after the others (a
// lossless call passes none of them: the call of old): the memory fields Q_O, Q_N and their 7
// coefficients (eta, eps_O, eps_N, a_O, a_N, g_O, g_N); false: some given, not all, or
// inconsistent sizes or types
using Opt = std::optional<ffi::AnyBuffer>;
using OptRet = std::optional<ffi::Result<ffi::AnyBuffer>>;

template <typename T, typename Args>
bool bind_relax(Args& a, int64_t n_cells, ffi::DataType type, const Opt& rq0_, const Opt& rq1_, const Opt& relax_,
                OptRet& rq0_o, OptRet& rq1_o) {
  if (!rq0_ && !rq1_ && !relax_ && !rq0_o && !rq1_o) return true;  // lossless: the call of old
  if (!rq0_ || !rq1_ || !relax_ || !rq0_o || !rq1_o) return false;
  const ffi::AnyBuffer &rq0 = *rq0_, &rq1 = *rq1_, &relax = *relax_;
  if (int64_t(rq0.element_count()) != n_cells || int64_t(rq1.element_count()) != n_cells ||
      relax.element_count() != 7 || relax.element_type() != type || rq0.element_type() != type ||
      rq1.element_type() != type)
    return false;
  a.rq[0] = out_from<T>(*rq0_o, rq0);
  a.rq[1] = out_from<T>(*rq1_o, rq1);
  const T* r = reinterpret_cast<const T*>(relax.untyped_data());
  a.r_eta = r[0];
  a.r_eps[0] = r[1];
  a.r_eps[1] = r[2];
  a.r_a[0] = r[3];
  a.r_a[1] = r[4];
  a.r_g[0] = r[5];
  a.r_g[1] = r[6];
  return true;
}

const char* kRelax = "air absorption needs two memory fields of the grid's shape and 7 coefficients";

// the extra buffers of a call with PML layers (difflattice_layered): the boxes' packed fields (parts
// px, py of each box; faces wx, wy of each box; the ring correction of each box on the r_hi
// rings), the boxes (n, 4: r0 r1 c0 c1), the PML factors and the ring correction's factors
struct LayerBind {
  ffi::AnyBuffer lp, lw, lc, boxes, axc, bxc, axf, bxf, ayc, byc, ayf, byf, rad_decay, rad_drive;
  ffi::Result<ffi::AnyBuffer>*lp_o, *lw_o, *lc_o;
};

template <typename T>
const char* bind_layers(dl::LayerArgs<T>& la, LayerBind& lb, const dl::LeapfrogArgs<T>& a) {
  const int64_t nx = a.nx, ny = a.ny;
  bool ok = true;
  la.axc = dl::make_coef<T>(lb.axc, nx, ny, &ok);
  la.bxc = dl::make_coef<T>(lb.bxc, nx, ny, &ok);
  la.axf = dl::make_coef<T>(lb.axf, nx + 1, ny, &ok);
  la.bxf = dl::make_coef<T>(lb.bxf, nx + 1, ny, &ok);
  la.ayc = dl::make_coef<T>(lb.ayc, nx, ny, &ok);
  la.byc = dl::make_coef<T>(lb.byc, nx, ny, &ok);
  la.ayf = dl::make_coef<T>(lb.ayf, nx, ny + 1, &ok);
  la.byf = dl::make_coef<T>(lb.byf, nx, ny + 1, &ok);
  auto row_layout = [](const dl::Coef<T>& c) { return !c.present() || c.mode == dl::kScalar || c.mode == dl::kPerRow; };
  auto col_layout = [](const dl::Coef<T>& c) { return !c.present() || c.mode == dl::kPerCol; };
  ok = ok && row_layout(la.axc) && row_layout(la.bxc) && row_layout(la.axf) && row_layout(la.bxf) &&
       col_layout(la.ayc) && col_layout(la.byc) && col_layout(la.ayf) && col_layout(la.byf);
  if (!ok) return "PML factors of an unsupported layout";
  la.iso_faces = a.iso && ((a.bx.present() && !a.bx.in_register()) ||
                            (a.by.present() && a.by.mode != dl::kScalar && a.by.mode != dl::kPerCol));
  if (la.iso_faces) dl::materialise(a.by, nx, ny + 1, la.by_full);
  la.w = int64_t(lb.rad_decay.element_count());
  if (la.w > ny || int64_t(lb.rad_drive.element_count()) != la.w) return "radial PML arrays of inconsistent sizes";
  la.rad_decay = reinterpret_cast<const T*>(lb.rad_decay.untyped_data());
  la.rad_drive = reinterpret_cast<const T*>(lb.rad_drive.untyped_data());
  T* lp = out_from<T>(*lb.lp_o, lb.lp);
  T* lw = out_from<T>(*lb.lw_o, lb.lw);
  T* lc = out_from<T>(*lb.lc_o, lb.lc);
  const int32_t* bx = reinterpret_cast<const int32_t*>(lb.boxes.untyped_data());
  const int64_t n_boxes = int64_t(lb.boxes.element_count() / 4);
  int64_t op = 0, ow = 0, oc = 0;
  la.of_row.assign(nx, {});
  std::vector<int64_t> covered(nx, 0);
  for (int64_t k = 0; k < n_boxes; ++k) {
    dl::LayerBox<T> b{};
    b.r0 = bx[4 * k];
    b.r1 = bx[4 * k + 1];
    b.c0 = bx[4 * k + 2];
    b.c1 = bx[4 * k + 3];
    if (b.r0 < 0 || b.r1 > nx || b.r0 >= b.r1 || b.c0 < 0 || b.c1 > ny || b.c0 >= b.c1) return "a layer box outside the grid";
    const int64_t nr = b.r1 - b.r0, nc = b.c1 - b.c0;
    b.px = lp + op;
    b.py = lp + op + nr * nc;
    op += 2 * nr * nc;
    b.wx = lw + ow;
    b.wy = lw + ow + (nr + 1) * nc;
    ow += (nr + 1) * nc + nr * (nc + 1);
    if (la.w && b.c1 == ny) {
      if (nc < la.w) return "a box on the r_hi rings narrower than the layer";
      b.cr = lc + oc;
      oc += nr * la.w;
    }
    for (int64_t i = b.r0; i < b.r1; ++i) {
      la.of_row[i].push_back(int(k));
      covered[i] += nc;
    }
    la.boxes.push_back(b);
  }
  if (op != int64_t(lb.lp.element_count()) || ow != int64_t(lb.lw.element_count()) || oc != int64_t(lb.lc.element_count()))
    return "layer fields whose sizes do not match the boxes";
  la.whole_row.assign(nx, 0);
  for (int64_t i = 0; i < nx; ++i) {
    if (covered[i] > ny) return "overlapping layer boxes";
    la.whole_row[i] = covered[i] == ny;
  }
  return nullptr;
}

template <typename T>
ffi::Error leapfrog_typed(ffi::AnyBuffer p, ffi::AnyBuffer pp, ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by,
                          ffi::AnyBuffer qs, ffi::AnyBuffer keep, ffi::AnyBuffer sponge, ffi::AnyBuffer my_lo,
                          ffi::AnyBuffer my_hi, ffi::AnyBuffer src_cells,
                          ffi::AnyBuffer src_hard, ffi::AnyBuffer src_vals, ffi::AnyBuffer rec_cells,
                          ffi::AnyBuffer zero_cells, ffi::AnyBuffer ph_cells, ffi::AnyBuffer ph_cos,
                          ffi::AnyBuffer ph_sin, ffi::AnyBuffer ph_re, ffi::AnyBuffer ph_im, ffi::AnyBuffer p_max,
                          ffi::AnyBuffer p_sq, ffi::AnyBuffer arrival, ffi::AnyBuffer n0,
                          ffi::Result<ffi::AnyBuffer> p_o, ffi::Result<ffi::AnyBuffer> pp_o,
                          ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> ph_re_o,
                          ffi::Result<ffi::AnyBuffer> ph_im_o, ffi::Result<ffi::AnyBuffer> p_max_o,
                          ffi::Result<ffi::AnyBuffer> p_sq_o, ffi::Result<ffi::AnyBuffer> arrival_o,
                          Opt rq0, Opt rq1, Opt relax, OptRet rq0_o, OptRet rq1_o,
                          int64_t n_steps, int64_t threads, int64_t levels, int64_t bands, int64_t combine,
                          int64_t stencil, double eta, double threshold, LayerBind* lb) {
  auto dims = p.dimensions();
  if (dims.size() != 2) return ffi::Error::InvalidArgument("difflattice_leapfrog: the field must be 2-D");
  const int64_t nx = dims[0], ny = dims[1];
  dl::LeapfrogArgs<T> a{};
  a.nx = nx;
  a.ny = ny;
  a.n_steps = n_steps;
  a.n_threads = int(threads);
  a.levels = int(levels);
  a.bands = bands != 0;
  a.combine = int(combine);
  a.iso = stencil == 1;
  bool ok = true;
  a.K = dl::make_coef<T>(K, nx, ny, &ok);
  a.bx = dl::make_coef<T>(bx, nx + 1, ny, &ok);
  a.by = dl::make_coef<T>(by, nx, ny + 1, &ok);
  a.qs = dl::make_coef<T>(qs, nx, ny, &ok);
  a.keep = dl::make_coef<T>(keep, nx, ny, &ok);
  a.sponge = dl::make_coef<T>(sponge, nx, ny, &ok);
  a.my_lo = dl::make_coef<T>(my_lo, nx, ny, &ok);
  a.my_hi = dl::make_coef<T>(my_hi, nx, ny, &ok);
  ok = ok && (a.my_lo.present() == a.my_hi.present());
  if (!ok || !a.K.present())
    return ffi::Error::InvalidArgument("difflattice_leapfrog: a coefficient array does not broadcast to the grid");
  if (!inside(src_cells, nx, ny) || !inside(rec_cells, nx, ny) || !inside(zero_cells, nx, ny) ||
      !inside(ph_cells, nx, ny))
    return ffi::Error::InvalidArgument(kOutside);
  a.p = out_from<T>(p_o, p);
  a.pp = out_from<T>(pp_o, pp);
  a.eta = eta;
  bind_cells<T>(a.cells, ny, src_cells, src_hard, src_vals, rec_cells, rec_o, ph_cells, ph_cos, ph_sin,
                out_from<T>(ph_re_o, ph_re), out_from<T>(ph_im_o, ph_im), out_from<T>(p_max_o, p_max),
                out_from<T>(p_sq_o, p_sq), out_from<int32_t>(arrival_o, arrival), n0, threshold);
  a.cells.zero_cells = reinterpret_cast<const int32_t*>(zero_cells.untyped_data());
  a.cells.n_zero = int64_t(zero_cells.element_count() / 2);
  if (!bind_relax<T>(a, nx * ny, p.element_type(), rq0, rq1, relax, rq0_o, rq1_o))
    return ffi::Error::InvalidArgument(std::string("difflattice_leapfrog: ") + kRelax);
  if (a.rq[0] && combine == dl::kAdj)
    return ffi::Error::InvalidArgument("difflattice_leapfrog: the adjoint mode has no air absorption");
  dl::LayerArgs<T> la;
  if (lb) {
    if (combine == dl::kAdj) return ffi::Error::InvalidArgument("difflattice_layered: the adjoint mode has no PML layers");
    if (const char* err = bind_layers<T>(la, *lb, a)) return ffi::Error::InvalidArgument(std::string("difflattice_layered: ") + err);
    a.layers = &la;
  }
  if (!dl::leapfrog<T>(a)) return ffi::Error::InvalidArgument("difflattice_leapfrog: unsupported coefficient layout");
  return ffi::Error::Success();
}

ffi::Error leapfrog_impl(ffi::AnyBuffer p, ffi::AnyBuffer pp, ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by,
                         ffi::AnyBuffer qs, ffi::AnyBuffer keep, ffi::AnyBuffer sponge, ffi::AnyBuffer my_lo,
                         ffi::AnyBuffer my_hi, ffi::AnyBuffer src_cells,
                         ffi::AnyBuffer src_hard, ffi::AnyBuffer src_vals, ffi::AnyBuffer rec_cells,
                         ffi::AnyBuffer zero_cells, ffi::AnyBuffer ph_cells, ffi::AnyBuffer ph_cos,
                         ffi::AnyBuffer ph_sin, ffi::AnyBuffer ph_re, ffi::AnyBuffer ph_im, ffi::AnyBuffer p_max,
                         ffi::AnyBuffer p_sq, ffi::AnyBuffer arrival, ffi::AnyBuffer n0,
                         ffi::Result<ffi::AnyBuffer> p_o, ffi::Result<ffi::AnyBuffer> pp_o,
                         ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> ph_re_o,
                         ffi::Result<ffi::AnyBuffer> ph_im_o, ffi::Result<ffi::AnyBuffer> p_max_o,
                         ffi::Result<ffi::AnyBuffer> p_sq_o, ffi::Result<ffi::AnyBuffer> arrival_o,
                         Opt rq0, Opt rq1, Opt relax, OptRet rq0_o, OptRet rq1_o, int64_t n_steps, int64_t threads, int64_t levels, int64_t bands, int64_t combine,
                         int64_t stencil, double eta, double threshold) {
#define DL_ARGS                                                                                                 \
  p, pp, K, bx, by, qs, keep, sponge, my_lo, my_hi, src_cells, src_hard, src_vals, rec_cells, zero_cells, ph_cells, ph_cos, \
      ph_sin, ph_re, ph_im, p_max, p_sq, arrival, n0, p_o, pp_o, rec_o, ph_re_o, ph_im_o, p_max_o, p_sq_o,      \
      arrival_o, rq0, rq1, relax, rq0_o, rq1_o, n_steps, threads, levels, bands, combine, stencil, eta, threshold, \
      nullptr
  switch (p.element_type()) {
    case ffi::DataType::F32:
      return leapfrog_typed<float>(DL_ARGS);
    case ffi::DataType::F64:
      return leapfrog_typed<double>(DL_ARGS);
    default:
      return ffi::Error::InvalidArgument("difflattice_leapfrog: float32 or float64 fields only");
  }
#undef DL_ARGS
}

// a leapfrog call with PML layers: the leapfrog's arguments, then the layers' (`LayerBind`)
ffi::Error layered_impl(ffi::AnyBuffer p, ffi::AnyBuffer pp, ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by,
                        ffi::AnyBuffer qs, ffi::AnyBuffer keep, ffi::AnyBuffer sponge, ffi::AnyBuffer my_lo,
                        ffi::AnyBuffer my_hi, ffi::AnyBuffer src_cells, ffi::AnyBuffer src_hard,
                        ffi::AnyBuffer src_vals, ffi::AnyBuffer rec_cells, ffi::AnyBuffer zero_cells,
                        ffi::AnyBuffer ph_cells, ffi::AnyBuffer ph_cos, ffi::AnyBuffer ph_sin, ffi::AnyBuffer ph_re,
                        ffi::AnyBuffer ph_im, ffi::AnyBuffer p_max, ffi::AnyBuffer p_sq, ffi::AnyBuffer arrival,
                        ffi::AnyBuffer n0, ffi::AnyBuffer lp, ffi::AnyBuffer lw, ffi::AnyBuffer lc,
                        ffi::AnyBuffer boxes, ffi::AnyBuffer axc, ffi::AnyBuffer bxc, ffi::AnyBuffer axf,
                        ffi::AnyBuffer bxf, ffi::AnyBuffer ayc, ffi::AnyBuffer byc, ffi::AnyBuffer ayf,
                        ffi::AnyBuffer byf, ffi::AnyBuffer rad_decay, ffi::AnyBuffer rad_drive,
                        ffi::Result<ffi::AnyBuffer> p_o, ffi::Result<ffi::AnyBuffer> pp_o,
                        ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> ph_re_o,
                        ffi::Result<ffi::AnyBuffer> ph_im_o, ffi::Result<ffi::AnyBuffer> p_max_o,
                        ffi::Result<ffi::AnyBuffer> p_sq_o, ffi::Result<ffi::AnyBuffer> arrival_o,
                        ffi::Result<ffi::AnyBuffer> lp_o, ffi::Result<ffi::AnyBuffer> lw_o,
                        ffi::Result<ffi::AnyBuffer> lc_o, Opt rq0, Opt rq1, Opt relax, OptRet rq0_o, OptRet rq1_o,
                        int64_t n_steps, int64_t threads, int64_t levels, int64_t bands, int64_t combine,
                        int64_t stencil, double eta, double threshold) {
  LayerBind lb{lp, lw, lc, boxes, axc, bxc, axf, bxf, ayc, byc, ayf, byf, rad_decay, rad_drive, &lp_o, &lw_o, &lc_o};
  if (sponge.element_count() || zero_cells.element_count())
    return ffi::Error::InvalidArgument("difflattice_layered: no sponge or zeroed cells with PML layers");
#define DL_ARGS                                                                                                 \
  p, pp, K, bx, by, qs, keep, sponge, my_lo, my_hi, src_cells, src_hard, src_vals, rec_cells, zero_cells, ph_cells, ph_cos, \
      ph_sin, ph_re, ph_im, p_max, p_sq, arrival, n0, p_o, pp_o, rec_o, ph_re_o, ph_im_o, p_max_o, p_sq_o,      \
      arrival_o, rq0, rq1, relax, rq0_o, rq1_o, n_steps, threads, levels, bands, combine, stencil, eta, threshold, &lb
  switch (p.element_type()) {
    case ffi::DataType::F32:
      return leapfrog_typed<float>(DL_ARGS);
    case ffi::DataType::F64:
      return leapfrog_typed<double>(DL_ARGS);
    default:
      return ffi::Error::InvalidArgument("difflattice_layered: float32 or float64 fields only");
  }
#undef DL_ARGS
}

template <typename T>
ffi::Error adjoint_chunk_typed(ffi::AnyBuffer p_end, ffi::AnyBuffer pp_end, ffi::AnyBuffer x, ffi::AnyBuffer h,
                               ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by, ffi::AnyBuffer ml,
                               ffi::AnyBuffer mh, ffi::AnyBuffer vol, ffi::AnyBuffer area, ffi::AnyBuffer src_cells,
                               ffi::AnyBuffer src_hard, ffi::AnyBuffer src_vals, ffi::AnyBuffer inj_cells,
                               ffi::AnyBuffer inj_vals, ffi::AnyBuffer rec_cells, ffi::AnyBuffer zero_cells,
                               ffi::AnyBuffer dK, ffi::AnyBuffer dbx, ffi::AnyBuffer dby,
                               ffi::Result<ffi::AnyBuffer> x_o, ffi::Result<ffi::AnyBuffer> h_o,
                               ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> dK_o,
                               ffi::Result<ffi::AnyBuffer> dbx_o, ffi::Result<ffi::AnyBuffer> dby_o, int64_t n_steps,
                               int64_t threads, int64_t levels) {
  auto dims = x.dimensions();
  if (dims.size() != 2) return ffi::Error::InvalidArgument("difflattice_adjoint_chunk: the field must be 2-D");
  const int64_t nx = dims[0], ny = dims[1];
  const char* bad = "difflattice_adjoint_chunk: an argument has the wrong size";
  if (p_end.element_count() != size_t(nx * ny) || pp_end.element_count() != size_t(nx * ny) ||
      h.element_count() != size_t(nx * ny) || bx.element_count() != size_t((nx + 1) * ny) ||
      by.element_count() != size_t(nx * (ny + 1)) ||
      (ml.element_count() &&  // the ring metric, or none (a plane grid: four empty arrays)
       (ml.element_count() != size_t(ny) || mh.element_count() != size_t(ny) || vol.element_count() != size_t(ny) ||
        area.element_count() != size_t(ny + 1))) ||
      (dK.element_count() && dK.element_count() != size_t(nx * ny)) ||
      (dbx.element_count() && dbx.element_count() != size_t((nx + 1) * ny)) ||
      (dby.element_count() && dby.element_count() != size_t(nx * (ny + 1))) || n_steps < 1 ||
      src_vals.element_count() != size_t((n_steps + 2) * (src_cells.element_count() / 2)))
    return ffi::Error::InvalidArgument(bad);
  if (!inside(src_cells, nx, ny) || !inside(inj_cells, nx, ny) || !inside(rec_cells, nx, ny) ||
      !inside(zero_cells, nx, ny))
    return ffi::Error::InvalidArgument(kOutside);
  dl::AdjointChunkArgs<T> a{};
  a.nx = nx;
  a.ny = ny;
  a.len = n_steps;
  a.n_threads = int(threads);
  a.levels = int(levels);
  bool ok = true;
  a.K = dl::make_coef<T>(K, nx, ny, &ok);
  if (!ok || !a.K.present())
    return ffi::Error::InvalidArgument("difflattice_adjoint_chunk: K does not broadcast to the grid");
  auto ptr = [](const ffi::AnyBuffer& b) { return reinterpret_cast<const T*>(b.untyped_data()); };
  a.p_end = ptr(p_end);
  a.pp_end = ptr(pp_end);
  a.bx = ptr(bx);
  a.by = ptr(by);
  if (ml.element_count()) {
    a.ml = ptr(ml);
    a.mh = ptr(mh);
    a.vol = ptr(vol);
    a.area = ptr(area);
  }
  a.x = out_from<T>(x_o, x);
  a.h = out_from<T>(h_o, h);
  a.dK = out_from<T>(dK_o, dK);
  a.dbx = out_from<T>(dbx_o, dbx);
  a.dby = out_from<T>(dby_o, dby);
  a.src_cells = reinterpret_cast<const int32_t*>(src_cells.untyped_data());
  a.src_hard = reinterpret_cast<const int32_t*>(src_hard.untyped_data());
  a.src_vals = ptr(src_vals);
  a.n_src = int64_t(src_cells.element_count() / 2);
  std::vector<int32_t> soft(inj_cells.element_count() / 2, 0);
  a.adj.ny = ny;
  a.adj.src_cells = reinterpret_cast<const int32_t*>(inj_cells.untyped_data());
  a.adj.src_hard = soft.data();
  a.adj.src_vals = ptr(inj_vals);
  a.adj.n_src = int64_t(soft.size());
  a.adj.rec_cells = reinterpret_cast<const int32_t*>(rec_cells.untyped_data());
  a.adj.n_rec = int64_t(rec_cells.element_count() / 2);
  a.adj.rec_out = reinterpret_cast<T*>(rec_o->untyped_data());
  a.adj.zero_cells = reinterpret_cast<const int32_t*>(zero_cells.untyped_data());
  a.adj.n_zero = int64_t(zero_cells.element_count() / 2);
  dl::adjoint_chunk<T>(a);
  return ffi::Error::Success();
}

ffi::Error adjoint_chunk_impl(ffi::AnyBuffer p_end, ffi::AnyBuffer pp_end, ffi::AnyBuffer x, ffi::AnyBuffer h,
                              ffi::AnyBuffer K, ffi::AnyBuffer bx, ffi::AnyBuffer by, ffi::AnyBuffer ml,
                              ffi::AnyBuffer mh, ffi::AnyBuffer vol, ffi::AnyBuffer area, ffi::AnyBuffer src_cells,
                              ffi::AnyBuffer src_hard, ffi::AnyBuffer src_vals, ffi::AnyBuffer inj_cells,
                              ffi::AnyBuffer inj_vals, ffi::AnyBuffer rec_cells, ffi::AnyBuffer zero_cells,
                              ffi::AnyBuffer dK, ffi::AnyBuffer dbx, ffi::AnyBuffer dby,
                              ffi::Result<ffi::AnyBuffer> x_o, ffi::Result<ffi::AnyBuffer> h_o,
                              ffi::Result<ffi::AnyBuffer> rec_o, ffi::Result<ffi::AnyBuffer> dK_o,
                              ffi::Result<ffi::AnyBuffer> dbx_o, ffi::Result<ffi::AnyBuffer> dby_o, int64_t n_steps,
                              int64_t threads, int64_t levels) {
#define DL_ARGS                                                                                                   \
  p_end, pp_end, x, h, K, bx, by, ml, mh, vol, area, src_cells, src_hard, src_vals, inj_cells, inj_vals,     \
      rec_cells, zero_cells, dK, dbx, dby, x_o, h_o, rec_o, dK_o, dbx_o, dby_o, n_steps, threads, levels
  switch (x.element_type()) {
    case ffi::DataType::F32:
      return adjoint_chunk_typed<float>(DL_ARGS);
    case ffi::DataType::F64:
      return adjoint_chunk_typed<double>(DL_ARGS);
    default:
      return ffi::Error::InvalidArgument("difflattice_adjoint_chunk: float32 or float64 fields only");
  }
#undef DL_ARGS
}

}  // namespace

#define DL_BUFS_8 \
  .Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>().Arg<ffi::AnyBuffer>()
#define DL_RETS_4 .Ret<ffi::AnyBuffer>().Ret<ffi::AnyBuffer>().Ret<ffi::AnyBuffer>().Ret<ffi::AnyBuffer>()

// args: p pp K bx by qs keep sponge | my_lo my_hi src_cells src_hard src_vals rec_cells zero_cells
//       ph_cells | ph_cos ph_sin ph_re ph_im p_max p_sq arrival n0 | optional: rq0 rq1 relax (air
//       absorption: the memory fields Q_O, Q_N and their 7 coefficients; absent: lossless)
// rets: p pp rec ph_re ph_im p_max p_sq arrival | optional: rq0 rq1
#define DL_RELAX                                                                                             \
  .OptionalArg<ffi::AnyBuffer>().OptionalArg<ffi::AnyBuffer>().OptionalArg<ffi::AnyBuffer>().OptionalRet<ffi::AnyBuffer>() \
      .OptionalRet<ffi::AnyBuffer>()
XLA_FFI_DEFINE_HANDLER_SYMBOL(DifflatticeLeapfrog, leapfrog_impl,
                              ffi::Ffi::Bind() DL_BUFS_8 DL_BUFS_8.Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>() DL_RETS_4 DL_RETS_4 DL_RELAX.Attr<int64_t>("n_steps")
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("levels")
                                  .Attr<int64_t>("bands")
                                  .Attr<int64_t>("combine")
                                  .Attr<int64_t>("stencil")
                                  .Attr<double>("eta")
                                  .Attr<double>("threshold"));

// args: the leapfrog's 24 | lp lw lc boxes axc bxc axf bxf | ayc byc ayf byf rad_decay rad_drive |
//       optional: rq0 rq1 relax
// rets: the leapfrog's 8 | lp lw lc | optional: rq0 rq1
XLA_FFI_DEFINE_HANDLER_SYMBOL(DifflatticeLayered, layered_impl,
                              ffi::Ffi::Bind() DL_BUFS_8 DL_BUFS_8 DL_BUFS_8 DL_BUFS_8.Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>() DL_RETS_4 DL_RETS_4.Ret<ffi::AnyBuffer>()
                                  .Ret<ffi::AnyBuffer>()
                                  .Ret<ffi::AnyBuffer>() DL_RELAX.Attr<int64_t>("n_steps")
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("levels")
                                  .Attr<int64_t>("bands")
                                  .Attr<int64_t>("combine")
                                  .Attr<int64_t>("stencil")
                                  .Attr<double>("eta")
                                  .Attr<double>("threshold"));

// args: p_end pp_end x h K bx by ml | mh vol area src_cells src_hard src_vals inj_cells inj_vals |
//       rec_cells zero_cells dK dbx dby
// rets: x h rec dK dbx dby
XLA_FFI_DEFINE_HANDLER_SYMBOL(DifflatticeAdjointChunk, adjoint_chunk_impl,
                              ffi::Ffi::Bind() DL_BUFS_8 DL_BUFS_8.Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>()
                                  .Arg<ffi::AnyBuffer>() DL_RETS_4.Ret<ffi::AnyBuffer>()
                                  .Ret<ffi::AnyBuffer>()
                                  .Attr<int64_t>("n_steps")
                                  .Attr<int64_t>("threads")
                                  .Attr<int64_t>("levels"));
