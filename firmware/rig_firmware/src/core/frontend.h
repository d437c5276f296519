// Calibration of the microphone front end and the drive, and the front end's frequency response.
//
// Signal chain (docs/rig.md, "Microphone front end"): microphone -> preamplifier (fixed gain)
// -> 4th-order Butterworth anti-alias low-pass (two Sallen-Key stages, cut-off fc) -> PGA (gain
// steps) -> 12-bit ADC biased at mid-scale, sampled at 8 samples per carrier period. The firmware
// divides the front end's complex response at the carrier out of every reading, so amp_uV is
// the microphone's output voltage and phase_mdeg the lag of the microphone's carrier behind the
// drive (protocol "Field conventions"), not the lag of the ADC's input.
#pragma once

#include <math.h>
#include <stdint.h>

namespace rig {

constexpr int kMaxGains = 8;
constexpr double kPi = 3.14159265358979323846;

struct Calibration {
  double adc_uV_per_count = 3.3e6 / 4096.0;  // 3.3 V full scale, 12 bits
  double preamp_gain = 2.0;                  // fixed preamplifier gain, V/V
  uint8_t n_gains = 6;
  double pga_gain[kMaxGains] = {1, 2, 4, 8, 16, 32};  // MCP6S22 steps used, V/V
  double aa_cutoff_hz = 150000.0;            // -3 dB frequency of the anti-alias filter
  double driver_delay_ns = 0.0;              // drive electronics: timer edge to transducer terminals
  double lobe_range_m = 1.0;                 // lobe rig: turntable axis to microphone (gate prediction)
  double gain_error[kMaxGains] = {1, 1, 1, 1, 1, 1, 1, 1};  // measured/ideal per PGA step (calibration)
};

struct Cplx {
  double re, im;
};

inline Cplx cmul(Cplx a, Cplx b) { return {a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re}; }
inline Cplx cdiv(Cplx a, Cplx b) {
  double d = b.re * b.re + b.im * b.im;
  return {(a.re * b.re + a.im * b.im) / d, (a.im * b.re - a.re * b.im) / d};
}

// H(j f / fc) of a unit-gain 4th-order Butterworth low-pass: 1 / ((s^2 + 0.7654 s + 1)(s^2 + 1.8478 s + 1)).
// A signal cos(w t) comes out as |H| cos(w t + arg H): its lag grows by -arg H.
inline Cplx butterworth4(double f_hz, double fc_hz) {
  double w = f_hz / fc_hz;
  const double a1 = 2.0 * sin(kPi / 8.0) * 1.0, a2 = 2.0 * cos(kPi / 8.0);  // 0.7654, 1.8478
  Cplx s1 = {1.0 - w * w, a1 * w};
  Cplx s2 = {1.0 - w * w, a2 * w};
  return cdiv({1.0, 0.0}, cmul(s1, s2));
}

// Phase lag [rad] the filter adds at f, unwrapped (it grows from 0 to 2 pi with frequency).
inline double aa_lag_rad(double f_hz, double fc_hz) {
  double w = f_hz / fc_hz;
  const double a1 = 2.0 * sin(kPi / 8.0), a2 = 2.0 * cos(kPi / 8.0);
  return atan2(a1 * w, 1.0 - w * w) + atan2(a2 * w, 1.0 - w * w);
}

// Group delay [s] of the filter at f: d(lag)/d(omega), by a central difference.
inline double aa_group_delay_s(double f_hz, double fc_hz) {
  double df = 1e-3 * fc_hz;
  return (aa_lag_rad(f_hz + df, fc_hz) - aa_lag_rad(f_hz - df, fc_hz)) / (2.0 * kPi * 2.0 * df);
}

// Speed of sound in dry air [m/s] at `t_c` degC: 331.3 sqrt(1 + T / 273.15) (difflattice.air).
inline double speed_of_sound_m_s(double t_c) { return 331.3 * sqrt(1.0 + t_c / 273.15); }

}  // namespace rig
