// threads: the worker pool, the pipeline of blocked steps, row bands
// (part of the native kernels: included by lattice.cc, one translation unit)
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <optional>
#include <vector>
#include <atomic>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <type_traits>

#include <unistd.h>  // getpid
#if defined(__x86_64__) || defined(_M_X64)
#include <immintrin.h>
#define DL_PAUSE() _mm_pause()
#else
#define DL_PAUSE() ((void)0)
#endif

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

}  // namespace dl
