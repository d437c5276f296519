#include "rig.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

namespace rig {

namespace {

// Burst buffers (one rig per firmware): raw ADC codes, DC-free samples, their coherent sum over
// the bursts of a point, and an envelope.
uint16_t g_raw[kMaxSamples];
float g_dev[kMaxSamples];
float g_acc[kMaxSamples];
float g_env[kMaxSamples];

const Axis kHomeOrder[kNumAxes] = {Axis::StageZ, Axis::StageX, Axis::Turntable};  // retract the microphone first

int idx(Axis a) { return static_cast<int>(a); }

int64_t div_round(int64_t a, int64_t b) { return a >= 0 ? (a + b / 2) / b : -((-a + b / 2) / b); }

}  // namespace

RigConfig default_config() {
  RigConfig c{};
  c.fw_version = "1.0.0";
  c.rig_id = "DL-RIG-0001";
  // Turntable: 1.8 deg motor, 16 microsteps, 90:1 worm gear: 288000 steps/rev, 0.8 step/mdeg.
  c.axis[idx(Axis::Turntable)] = {4, 5, -180000, 180000, -182000, 2000, 0, 8000, 800, 8000};
  // Stage X and Z: SFU1204 ball screw (4 mm lead), 1.8 deg motor, 16 microsteps: 0.8 step/um.
  c.axis[idx(Axis::StageX)] = {4, 5, -100000, 100000, -102000, 2000, 0, 16000, 1600, 16000};
  // Z is the microphone's distance from the transducer face; its switch is at the far end.
  c.axis[idx(Axis::StageZ)] = {4, 5, 1000, 500000, 502000, 2000, 200000, 16000, 1600, 16000};
  c.heartbeat_ms = 1000;
  c.settle_ms = 50;
  c.burst_period_ms = 20;
  c.n_pre = 32;
  return c;
}

int32_t units_to_steps(const AxisConfig& a, int32_t units) {
  return static_cast<int32_t>(div_round(static_cast<int64_t>(units) * a.num, a.den));
}

Rig::Rig(Hal& hal, const RigConfig& cfg) : hal_(hal), cfg_(cfg) {}

void Rig::begin() {
  now_ = hal_.micros();
  last_tx_ = now_;
  uint16_t id = 0;
  while (id == 0) id = static_cast<uint16_t>(hal_.entropy());
  boot_id_ = id;
  homed_ = false;
  mode_ = Mode::Idle;
  for (int a = 0; a < kNumAxes; ++a)
    if (hal_.fitted(static_cast<Axis>(a))) hal_.stop(static_cast<Axis>(a));
  static const char* const kReason[] = {"POR", "EXT", "BOR", "WDT", "UNK"};
  send("BOOT,%s,%u,%s", cfg_.fw_version, static_cast<unsigned>(boot_id_),
       kReason[static_cast<int>(hal_.reset_reason())]);
}

// ----------------------------------------------------------------------------------------------
// Lines out
// ----------------------------------------------------------------------------------------------

void Rig::send(const char* fmt, ...) {
  char body[kMaxLine + 1];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(body, sizeof body, fmt, ap);
  va_end(ap);
  char line[kMaxLine + 1];
  size_t n = format_line(line, "%s", body);
  if (n) hal_.write(line, n);
  last_tx_ = now_;
}

void Rig::send_err(ErrCode code, const char* detail) { send("ERR,%s,%s", err_name(code), detail); }

void Rig::send_hbt() {
  bool scanning = mode_ == Mode::Scan;
  send("HBT,%lu,%s,%ld,%ld", static_cast<unsigned long>(uptime_us_ / 1000), scanning ? "SCAN" : "IDLE",
       static_cast<long>(scanning ? scan_.scan : last_scan_), static_cast<long>(scanning ? next_seq_ : last_next_seq_));
}

// ----------------------------------------------------------------------------------------------
// Lines in
// ----------------------------------------------------------------------------------------------

void Rig::handle_line(const char* line, size_t n) {
  ParseResult r = parse_line(line, n);
  if (r.err != ErrCode::None) {
    send_err(r.err, r.detail);
    return;
  }
  handle(r.cmd);
}

void Rig::handle(const Command& c) {
  switch (c.type) {
    case CmdType::Hello:
      send("IDN,%d,%s,%s,%u,%d,%s", kProtocolVersion, cfg_.fw_version, cfg_.rig_id, static_cast<unsigned>(boot_id_),
           homed_ ? 1 : 0, mode_ == Mode::Scan ? "SCAN" : "IDLE");
      break;
    case CmdType::Stat:
      send_hbt();
      break;
    case CmdType::Home:
      if (mode_ == Mode::Scan) {
        send_err(ErrCode::Busy, "HOME");
      } else if (mode_ == Mode::Idle) {  // HOME while homing: already on it
        homed_ = false;
        mode_ = Mode::Homing;
        home_axis_ = 0;
        home_phase_ = HomePhase::Start;
      }
      break;
    case CmdType::Lobe:
    case CmdType::Wave:
      if (mode_ != Mode::Idle)
        send_err(ErrCode::Busy, c.type == CmdType::Lobe ? "LOBE" : "WAVE");
      else
        start_scan(c);
      break;
    case CmdType::Abort:
      if (mode_ == Mode::Scan && c.scan != scan_.scan) {
        send_err(ErrCode::BadArg, "ABORT");
      } else if (mode_ == Mode::Scan) {
        end_scan("ABORTED");
      } else {
        send("END,%ld,0,ABORTED", static_cast<long>(c.scan));
      }
      break;
  }
}

// ----------------------------------------------------------------------------------------------
// Homing
// ----------------------------------------------------------------------------------------------

uint32_t Rig::step_homing() {
  while (home_axis_ < kNumAxes && !hal_.fitted(kHomeOrder[home_axis_])) ++home_axis_;
  if (home_axis_ >= kNumAxes) {
    homed_ = true;
    mode_ = Mode::Idle;
    send("ACK,HOME,0");
    return 0;
  }
  Axis a = kHomeOrder[home_axis_];
  const AxisConfig& ac = cfg_.axis[idx(a)];
  if (hal_.moving(a)) return 1000;
  int32_t dir = ac.home_units > ac.max_units ? 1 : -1;  // towards the switch
  int32_t travel = units_to_steps(ac, ac.max_units - ac.min_units + 4 * ac.backoff_units);
  int32_t backoff = units_to_steps(ac, ac.backoff_units);
  int32_t pos = hal_.position(a);
  auto fail = [&]() {
    for (int k = 0; k < kNumAxes; ++k)
      if (hal_.fitted(static_cast<Axis>(k))) hal_.stop(static_cast<Axis>(k));
    mode_ = Mode::Idle;
    homed_ = false;
    send_err(ErrCode::Limit, "HOME");
    return 0u;
  };
  switch (home_phase_) {
    case HomePhase::Start:
      hal_.enable(a, true);
      if (hal_.home_switch(a)) {  // already on the switch: get off it first
        hal_.move(a, pos - dir * backoff, ac.slow_sps, false);
        home_phase_ = HomePhase::Clear;
      } else {
        hal_.move(a, pos + dir * travel, ac.fast_sps, true);
        home_phase_ = HomePhase::Seek;
      }
      return 1000;
    case HomePhase::Clear:
      if (hal_.home_switch(a)) return fail();
      hal_.move(a, pos + dir * travel, ac.fast_sps, true);
      home_phase_ = HomePhase::Seek;
      return 1000;
    case HomePhase::Seek:
      if (!hal_.home_switch(a)) return fail();  // ran the whole travel without finding the switch
      hal_.move(a, pos - dir * backoff, ac.slow_sps, false);
      home_phase_ = HomePhase::Backoff;
      return 1000;
    case HomePhase::Backoff:
      if (hal_.home_switch(a)) return fail();  // stuck switch
      hal_.move(a, pos + dir * 2 * backoff, ac.slow_sps, true);
      home_phase_ = HomePhase::Approach;
      return 1000;
    case HomePhase::Approach:
      if (!hal_.home_switch(a)) return fail();
      hal_.set_position(a, units_to_steps(ac, ac.home_units));
      hal_.move(a, units_to_steps(ac, ac.park_units), ac.fast_sps, false);
      home_phase_ = HomePhase::Park;
      return 1000;
    case HomePhase::Park:
    case HomePhase::Next:
      ++home_axis_;
      home_phase_ = HomePhase::Start;
      return 0;
  }
  return 1000;
}

// ----------------------------------------------------------------------------------------------
// Scans
// ----------------------------------------------------------------------------------------------

double Rig::speed_of_sound() const { return speed_of_sound_m_s(temp_cC_ / 100.0); }

double Rig::predicted_arrival_s(int32_t seq) const {
  if (scan_.type == CmdType::Lobe) return cfg_.cal.lobe_range_m / speed_of_sound();
  double x = position_units(seq) * 1e-6, z = scan_.z_um * 1e-6;
  return sqrt(x * x + z * z) / speed_of_sound();
}

uint32_t Rig::window_samples(int32_t seq) const {
  double far;
  if (scan_.type == CmdType::Lobe) {
    far = cfg_.cal.lobe_range_m;
  } else {
    double x = fabs(position_units(seq) * 1e-6) + 0.05, z = scan_.z_um * 1e-6;  // 50 mm: the face's rim
    far = sqrt(x * x + z * z);
  }
  double c_min = speed_of_sound_m_s(-40.0);
  double window_s = 1.5 * far / c_min + (scan_.cycles + 12.0) / scan_.freq_hz;
  uint32_t n = static_cast<uint32_t>(ceil(window_s * kSpp * scan_.freq_hz));
  return (n + kSpp - 1) / kSpp * kSpp;
}

void Rig::start_scan(const Command& c) {
  const char* type = c.type == CmdType::Lobe ? "LOBE" : "WAVE";
  Axis axis = c.type == CmdType::Lobe ? Axis::Turntable : Axis::StageX;
  if (!hal_.fitted(axis) || (c.type == CmdType::Wave && !hal_.fitted(Axis::StageZ))) {
    send_err(ErrCode::BadCmd, type);  // this rig has no such axis
    return;
  }
  bool ok = 0 <= c.first_seq && c.first_seq < c.n && c.n <= kMaxPoints && 1 <= c.n_avg && c.n_avg <= kMaxAvg &&
            1 <= c.cycles && c.cycles <= kMaxCycles && kMinFreqHz <= static_cast<uint32_t>(c.freq_hz) &&
            static_cast<uint32_t>(c.freq_hz) <= kMaxFreqHz;
  if (ok) {
    Command saved = scan_;
    scan_ = c;
    const int32_t ends[2] = {0, c.n - 1};
    for (int32_t s : ends) ok = ok && window_samples(s) + cfg_.n_pre <= kMaxSamples;
    scan_ = saved;
  }
  if (!ok) {
    send_err(ErrCode::BadArg, type);
    return;
  }
  const AxisConfig& ac = cfg_.axis[idx(axis)];
  int64_t ends[2] = {c.start, static_cast<int64_t>(c.start) + static_cast<int64_t>(c.n - 1) * c.step};
  bool inside = true;
  for (int64_t e : ends) inside = inside && ac.min_units <= e && e <= ac.max_units;
  if (c.type == CmdType::Wave) {
    const AxisConfig& az = cfg_.axis[idx(Axis::StageZ)];
    inside = inside && az.min_units <= c.z_um && c.z_um <= az.max_units;
  }
  if (!inside) {
    send_err(ErrCode::Limit, type);
    return;
  }
  if (!homed_) {
    send_err(ErrCode::NotHomed, type);
    return;
  }
  scan_ = c;
  mode_ = Mode::Scan;
  next_seq_ = c.first_seq;
  sent_ = 0;
  phase_ = c.type == CmdType::Wave ? ScanPhase::MoveZ : ScanPhase::Move;
  wait_until_ = now_;
  temp_cC_ = hal_.temperature_cC();
  send("ACK,%s,%ld", type, static_cast<long>(c.scan));
  if (c.type == CmdType::Wave) hal_.move(Axis::StageZ, units_to_steps(cfg_.axis[idx(Axis::StageZ)], c.z_um),
                                         cfg_.axis[idx(Axis::StageZ)].move_sps, false);
}

void Rig::end_scan(const char* status) {
  for (int k = 0; k < kNumAxes; ++k)
    if (hal_.fitted(static_cast<Axis>(k)) && hal_.moving(static_cast<Axis>(k))) hal_.stop(static_cast<Axis>(k));
  last_scan_ = scan_.scan;
  last_next_seq_ = next_seq_;
  mode_ = Mode::Idle;
  send("END,%ld,%ld,%s", static_cast<long>(scan_.scan), static_cast<long>(sent_), status);
}

bool Rig::burst(bool ranging) {
  BurstRequest req{static_cast<uint32_t>(scan_.freq_hz), static_cast<uint16_t>(scan_.cycles), cfg_.n_pre,
                   cfg_.n_pre + n_window_};
  hal_.select(scan_.type == CmdType::Lobe ? MicInput::Lobe : MicInput::Wave, gain_);
  if (!hal_.acquire(req, g_raw)) return false;
  double dc, noise;
  dc_level(g_raw, cfg_.n_pre, &dc, &noise);
  int n = static_cast<int>(n_window_);
  bool clipped = false;
  float peak = 0.0f;
  for (int k = 0; k < n; ++k) {
    uint16_t x = g_raw[cfg_.n_pre + k];
    clipped = clipped || x <= 2 || x >= 4093;
    g_dev[k] = static_cast<float>(x - dc);
    peak = fmaxf(peak, fabsf(g_dev[k]));
  }
  noise_ = noise;
  const Calibration& cal = cfg_.cal;
  if (ranging) {
    ++ranging_tries_;
    bool settled = ranging_tries_ >= 2 * cal.n_gains;
    if (!settled && clipped && gain_ > 0) {  // clipped: the peak is unknown, one step down
      --gain_;
      return true;
    }
    if (!settled && !clipped) {  // the highest gain that keeps the peak below 60 % of full scale
      uint8_t best = 0;
      for (uint8_t g = 0; g < cal.n_gains; ++g)
        if (peak * cal.pga_gain[g] / cal.pga_gain[gain_] < 0.6 * 2047.0) best = g;
      if (best != gain_) {
        gain_ = best;
        return true;
      }
    }
    // the gain is right: place the gate on the plateau of this burst (or where it is expected)
    envelope(g_dev, n, g_env);
    Arrival a = find_arrival(g_env, n, noise);
    double fs = kSpp * static_cast<double>(scan_.freq_hz);
    double t = a.found ? a.t_samples : (predicted_arrival_s(next_seq_) + gd_s_) * fs;
    gate_len_ = plateau_gate(t, scan_.cycles, n, &gate_start_);
    if (gate_len_ == 0) gate_len_ = plateau_gate((predicted_arrival_s(next_seq_) + gd_s_) * fs, scan_.cycles, n,
                                                 &gate_start_);
    for (int k = 0; k < n; ++k) g_acc[k] = 0.0f;
    bursts_ = 0;
    amp_sum_ = amp_sum2_ = 0.0;
    phase_ = ScanPhase::Average;
    return true;
  }
  for (int k = 0; k < n; ++k) g_acc[k] += g_dev[k];
  IQ v = lockin(g_dev, gate_start_, gate_len_);
  double amp_uV = sqrt(v.i * v.i + v.q * v.q) * counts_to_uV();
  amp_sum_ += amp_uV;
  amp_sum2_ += amp_uV * amp_uV;
  ++bursts_;
  return true;
}

double Rig::counts_to_uV() const {
  const Calibration& cal = cfg_.cal;
  return cal.adc_uV_per_count / (cal.preamp_gain * cal.pga_gain[gain_] * cal.gain_error[gain_] * h_mag_);
}

void Rig::finish_point() {
  int n = static_cast<int>(n_window_);
  double inv = 1.0 / bursts_;
  for (int k = 0; k < n; ++k) g_acc[k] = static_cast<float>(g_acc[k] * inv);
  double mean = amp_sum_ * inv;
  double var = bursts_ > 1 ? (amp_sum2_ - bursts_ * mean * mean) / (bursts_ - 1) : 0.0;
  double sd = var > 0 ? sqrt(var) : 0.0;
  double f = scan_.freq_hz, fs = kSpp * f;
  // the carrier's lag behind the drive at the microphone: the ADC's lag less the front end's and
  // the driver's, reduced to [0, 360000) mdeg
  IQ v = lockin(g_acc, gate_start_, gate_len_);
  double lag = atan2(v.q, v.i) - h_lag_rad_ - 2.0 * kPi * f * cfg_.cal.driver_delay_ns * 1e-9;
  int64_t mdeg = static_cast<int64_t>(llround(lag * 180000.0 / kPi)) % 360000;
  if (mdeg < 0) mdeg += 360000;
  envelope(g_acc, n, g_env);
  Arrival a = find_arrival(g_env, n, noise_ / sqrt(static_cast<double>(bursts_)));
  double tof_s = a.found ? a.t_samples / fs - gd_s_ - cfg_.cal.driver_delay_ns * 1e-9 : predicted_arrival_s(next_seq_);
  long tof_ns = lround(tof_s * 1e9);
  int32_t temp = hal_.temperature_cC();
  int32_t pos = position_units(next_seq_);
  if (scan_.type == CmdType::Lobe) {
    send("LOB,%ld,%ld,%ld,%ld,%ld,%ld,%ld", static_cast<long>(scan_.scan), static_cast<long>(next_seq_),
         static_cast<long>(pos), lround(mean), lround(sd), tof_ns, static_cast<long>(temp));
  } else {
    send("WAV,%ld,%ld,%ld,%ld,%ld,%ld,%ld,%ld", static_cast<long>(scan_.scan), static_cast<long>(next_seq_),
         static_cast<long>(pos), static_cast<long>(scan_.z_um), tof_ns, static_cast<long>(mdeg), lround(mean),
         static_cast<long>(temp));
  }
}

uint32_t Rig::step_scan() {
  Axis axis = scan_axis();
  const AxisConfig& ac = cfg_.axis[idx(axis)];
  switch (phase_) {
    case ScanPhase::MoveZ:
      if (hal_.moving(Axis::StageZ)) return 1000;
      phase_ = ScanPhase::Move;
      return 0;
    case ScanPhase::Move: {
      int32_t target = units_to_steps(ac, position_units(next_seq_));
      if (hal_.position(axis) != target && !hal_.moving(axis)) {
        hal_.move(axis, target, ac.move_sps, false);
        return 1000;
      }
      if (hal_.moving(axis)) {
        if (hal_.home_switch(axis)) {  // the axis ran into its switch: lost steps or a collision
          homed_ = false;
          end_scan("FAULT");
        }
        return 1000;
      }
      phase_ = ScanPhase::Settle;
      wait_until_ = now_ + cfg_.settle_ms * 1000;
      return cfg_.settle_ms * 1000;
    }
    case ScanPhase::Settle: {
      if (!due(wait_until_)) break;
      temp_cC_ = hal_.temperature_cC();
      n_window_ = window_samples(next_seq_);
      double f = scan_.freq_hz;
      Cplx h = butterworth4(f, cfg_.cal.aa_cutoff_hz);
      h_mag_ = sqrt(h.re * h.re + h.im * h.im);
      h_lag_rad_ = aa_lag_rad(f, cfg_.cal.aa_cutoff_hz);
      gd_s_ = aa_group_delay_s(f, cfg_.cal.aa_cutoff_hz) + cfg_.cal.driver_delay_ns * 1e-9;
      ranging_tries_ = 0;
      phase_ = ScanPhase::Range;
      return 0;
    }
    case ScanPhase::Range:
    case ScanPhase::Average:
      if (!due(wait_until_)) break;
      if (!burst(phase_ == ScanPhase::Range)) {
        end_scan("FAULT");
        return 0;
      }
      wait_until_ = now_ + cfg_.burst_period_ms * 1000;
      if (phase_ == ScanPhase::Average && bursts_ >= scan_.n_avg) phase_ = ScanPhase::Report;
      return cfg_.burst_period_ms * 1000;
    case ScanPhase::Report:
      finish_point();
      ++next_seq_;
      ++sent_;
      if (next_seq_ >= scan_.n) {
        end_scan("OK");
        return 0;
      }
      phase_ = ScanPhase::Move;
      return 0;
  }
  int32_t left = static_cast<int32_t>(wait_until_ - now_);
  return left > 0 ? static_cast<uint32_t>(left) : 0;
}

// ----------------------------------------------------------------------------------------------
// Main loop
// ----------------------------------------------------------------------------------------------

uint32_t Rig::poll() {
  uint32_t t = hal_.micros();
  uptime_us_ += static_cast<uint32_t>(t - now_);
  now_ = t;
  hal_.kick_watchdog();
  uint8_t buf[64];
  size_t got = hal_.read(buf, sizeof buf);
  for (size_t i = 0; i < got; ++i) {
    if (!reader_.feed(buf[i])) continue;
    if (reader_.overflow()) {
      send_err(ErrCode::TooLong, "-");
      reader_.reset();
    } else {
      handle_line(reader_.line(), reader_.size());
    }
  }
  uint32_t wait = 10000;
  if (mode_ == Mode::Homing) wait = step_homing();
  else if (mode_ == Mode::Scan) wait = step_scan();
  uint32_t hb = cfg_.heartbeat_ms * 1000;
  uint32_t quiet = static_cast<uint32_t>(now_ - last_tx_);
  if (quiet >= hb) {
    send_hbt();
    quiet = 0;
  }
  uint32_t to_hb = hb - quiet;
  if (got == sizeof buf) wait = 0;  // more input waiting
  return wait < to_hb ? wait : to_hb;
}

}  // namespace rig
