#include "lockin.h"

#include <math.h>

namespace rig {

namespace {
// cos and sin of 2 pi k / 8
const float kCos[kSpp] = {1.0f, 0.70710678f, 0.0f, -0.70710678f, -1.0f, -0.70710678f, 0.0f, 0.70710678f};
const float kSin[kSpp] = {0.0f, 0.70710678f, 1.0f, 0.70710678f, 0.0f, -0.70710678f, -1.0f, -0.70710678f};
}  // namespace

void dc_level(const uint16_t* x, int n_pre, double* dc, double* noise_rms) {
  double s = 0, s2 = 0;
  for (int k = 0; k < n_pre; ++k) {
    s += x[k];
    s2 += static_cast<double>(x[k]) * x[k];
  }
  double m = n_pre > 0 ? s / n_pre : 2048.0;
  double v = n_pre > 1 ? (s2 - n_pre * m * m) / (n_pre - 1) : 0.0;
  *dc = m;
  *noise_rms = v > 0 ? sqrt(v) : 0.0;
}

IQ lockin(const float* d, int start, int len) {
  double i = 0, q = 0;
  for (int k = start; k < start + len; ++k) {
    i += static_cast<double>(d[k]) * kCos[k % kSpp];
    q += static_cast<double>(d[k]) * kSin[k % kSpp];
  }
  if (len <= 0) return {0, 0};
  return {2.0 * i / len, 2.0 * q / len};
}

void envelope(const float* d, int n, float* env) {
  for (int k = 0; k < n; ++k) {
    if (k < kSpp - 1) {
      env[k] = 0.0f;
      continue;
    }
    IQ v = lockin(d, k - kSpp + 1, kSpp);
    env[k] = static_cast<float>(sqrt(v.i * v.i + v.q * v.q));
  }
}

Arrival find_arrival(const float* env, int n, double noise_rms) {
  Arrival a{false, 0.0, 0.0f};
  int kp = 0;
  for (int k = 0; k < n; ++k)
    if (env[k] > a.peak) {
      a.peak = env[k];
      kp = k;
    }
  // one-period envelope of white noise of rms s: about 2 s / sqrt(kSpp) rms; demand 8 times that
  // (and a few counts, for the quantisation of a quiet input)
  double floor = 8.0 * 2.0 * (noise_rms > 0.3 ? noise_rms : 0.3) / sqrt(static_cast<double>(kSpp));
  if (a.peak <= floor) return a;
  float half = 0.5f * a.peak;
  if (env[kSpp - 1] >= half) {  // already above half at the first full window
    a.t_samples = (kSpp - 1) - 0.5 * (kSpp - 1);
    a.found = true;
    return a;
  }
  for (int k = kSpp; k <= kp; ++k) {
    if (env[k] >= half) {
      double frac = (half - env[k - 1]) / static_cast<double>(env[k] - env[k - 1]);
      a.t_samples = (k - 1) + frac - 0.5 * (kSpp - 1);
      a.found = true;
      return a;
    }
  }
  return a;
}

int plateau_gate(double arrival_samples, int cycles, int n, int* start) {
  int s = static_cast<int>(lround(arrival_samples)) + ((cycles + 1) / 2) * kSpp;
  int periods = cycles / 2 - 1;
  if (periods < 1) periods = 1;
  int len = periods * kSpp;
  if (s < 0) s = 0;
  while (len > 0 && s + len > n) len -= kSpp;
  *start = s;
  return len > 0 ? len : 0;
}

}  // namespace rig
