// Lock-in (I/Q) demodulation of the microphone's bursts, sampled coherently with the drive at
// kSpp samples per carrier period.
//
// Post-trigger sample k of a burst, d[k] (ADC counts, DC removed), is at t = k / fs with
// fs = kSpp * f. For d = A cos(w t - phi) over whole periods,
//   I = (2/M) sum d[k] cos(2 pi k / kSpp) = A cos(phi),  Q = (2/M) sum d[k] sin(2 pi k / kSpp) = A sin(phi),
// so A = hypot(I, Q) and the lag of the carrier behind the drive is phi = atan2(Q, I): a pure
// delay tau gives phi = w tau (mod 2 pi), the protocol's sign of phase_mdeg. The envelope is the
// same sum over a sliding window of one period (which cancels the 2w term exactly); its arrival
// is where it first crosses half its peak (the protocol's threshold crossing).
#pragma once

#include <stdint.h>

namespace rig {

constexpr int kSpp = 8;  // ADC samples per carrier period

struct IQ {
  double i, q;  // counts; amplitude hypot(i, q), lag atan2(q, i)
};

// Mean and rms deviation of the n_pre samples before the drive.
void dc_level(const uint16_t* x, int n_pre, double* dc, double* noise_rms);

// Lock-in over post-trigger samples [start, start + len) of d (len a multiple of kSpp).
IQ lockin(const float* d, int start, int len);

// env[k] = amplitude of the one-period lock-in ending at k (k >= kSpp - 1; earlier entries 0).
// The window ending at k is centred on k - (kSpp - 1) / 2.
void envelope(const float* d, int n, float* env);

struct Arrival {
  bool found;        // the envelope rose clearly above the noise
  double t_samples;  // half-peak crossing, centre of the window (post-trigger samples)
  float peak;        // envelope peak, counts
};

// Half-peak crossing of the envelope; `noise_rms` is the rms of one ADC sample's noise (counts).
Arrival find_arrival(const float* env, int n, double noise_rms);

// Gate of whole periods on the burst's plateau: from arrival + ceil(N/2) periods, for
// max(1, floor(N/2) - 1) periods (ends a period before the burst does), clipped to [0, n).
// Returns the length (multiple of kSpp, possibly 0) and the start in *start.
int plateau_gate(double arrival_samples, int cycles, int n, int* start);

}  // namespace rig
