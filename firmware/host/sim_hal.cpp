#include "sim_hal.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <cmath>
#include <fstream>
#include <sstream>

namespace sim {

using rig::Axis;

// ----------------------------------------------------------------------------------------------
// Ground truth
// ----------------------------------------------------------------------------------------------

bool Table::at(double x, double* amp_out, double* lag_out, double* tof_out) const {
  size_t n = pos.size();
  if (n < 2 || x < pos.front() - 1e-9 || x > pos.back() + 1e-9) return false;
  size_t i = 1;
  while (i < n - 1 && pos[i] < x) ++i;
  double w = (x - pos[i - 1]) / (pos[i] - pos[i - 1]);
  w = w < 0 ? 0 : (w > 1 ? 1 : w);
  *amp_out = amp[i - 1] + w * (amp[i] - amp[i - 1]);
  *lag_out = lag_rad[i - 1] + w * (lag_rad[i] - lag_rad[i - 1]);
  *tof_out = tof_s[i - 1] + w * (tof_s[i] - tof_s[i - 1]);
  return true;
}

static bool read_rows(std::istream& in, size_t n, Table* t, std::string* err, const char* what) {
  for (size_t k = 0; k < n; ++k) {
    double x, re, im, tof_ns;
    if (!(in >> x >> re >> im >> tof_ns)) {
      *err = std::string("truth table: ") + what + " section has fewer rows than announced";
      return false;
    }
    double lag = std::atan2(im, re);
    if (!t->lag_rad.empty()) {  // unwrap along the scan coordinate
      double prev = t->lag_rad.back();
      while (lag - prev > M_PI) lag -= 2 * M_PI;
      while (lag - prev < -M_PI) lag += 2 * M_PI;
    }
    if (!t->pos.empty() && x <= t->pos.back()) {
      *err = std::string("truth table: ") + what + " positions must increase";
      return false;
    }
    t->pos.push_back(x);
    t->amp.push_back(std::hypot(re, im));
    t->lag_rad.push_back(lag);
    t->tof_s.push_back(tof_ns * 1e-9);
  }
  return true;
}

bool Truth::load(const std::string& path, std::string* err) {
  std::ifstream f(path);
  if (!f) {
    *err = "cannot read the truth table " + path;
    return false;
  }
  std::stringstream clean;  // drop comments
  std::string line;
  while (std::getline(f, line)) clean << line.substr(0, line.find('#')) << '\n';
  std::string key;
  while (clean >> key) {
    if (key == "freq_hz") {
      clean >> freq_hz;
    } else if (key == "lobe") {
      size_t n;
      clean >> n;
      if (!read_rows(clean, n, &lobe, err, "lobe")) return false;
    } else if (key == "wave") {
      size_t n;
      clean >> wave_z_um >> n;
      if (!read_rows(clean, n, &wave, err, "wave")) return false;
    } else {
      *err = "truth table: unknown key '" + key + "' (expected freq_hz, lobe, wave)";
      return false;
    }
  }
  if (freq_hz <= 0 || (lobe.pos.empty() && wave.pos.empty())) {
    *err = "truth table " + path + ": needs freq_hz and a lobe or wave section";
    return false;
  }
  return true;
}

// ----------------------------------------------------------------------------------------------
// Clock and serial port
// ----------------------------------------------------------------------------------------------

static uint64_t real_ns() {
  timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<uint64_t>(ts.tv_sec) * 1000000000ull + static_cast<uint64_t>(ts.tv_nsec);
}

SimHal::SimHal(const Options& opt, const Truth& truth, const rig::RigConfig& cfg)
    : opt_(opt), truth_(truth), cfg_(cfg), rng_(opt.seed), real0_ns_(real_ns()) {
  // the axes stand wherever they were left at power-on; the switches are where the mechanics say
  for (int a = 0; a < rig::kNumAxes; ++a) {
    const rig::AxisConfig& ac = cfg.axis[a];
    Motor& m = motor_[a];
    m.switch_phys = rig::units_to_steps(ac, ac.home_units);
    m.dir_to_switch = ac.home_units > ac.max_units ? 1 : -1;
    double u = ac.min_units + (ac.max_units - ac.min_units) * std::uniform_real_distribution<double>(0.1, 0.9)(rng_);
    m.phys = rig::units_to_steps(ac, static_cast<int32_t>(u));
    m.offset = static_cast<int64_t>(rng_() % 100000);  // the step counter starts anywhere
  }
}

SimHal::~SimHal() { close_port(); }

uint64_t SimHal::now_us() { return static_cast<uint64_t>((real_ns() - real0_ns_) * opt_.speed / 1000.0); }

uint32_t SimHal::micros() { return static_cast<uint32_t>(now_us()); }

bool SimHal::open_port(std::string* err) {
  int m = posix_openpt(O_RDWR | O_NOCTTY);
  if (m < 0 || grantpt(m) != 0 || unlockpt(m) != 0) {
    *err = std::string("cannot open a pseudo-terminal: ") + strerror(errno);
    return false;
  }
  pts_ = ptsname(m);
  int s = open(pts_.c_str(), O_RDWR | O_NOCTTY);
  if (s >= 0) {
    termios t;
    tcgetattr(s, &t);
    cfmakeraw(&t);  // no echo of what the rig sends before a host opens the port
    tcsetattr(s, TCSANOW, &t);
    close(s);
  }
  fcntl(m, F_SETFL, fcntl(m, F_GETFL) | O_NONBLOCK);
  master_ = m;
  std::string tmp = opt_.link_path + ".tmp" + std::to_string(getpid());
  unlink(tmp.c_str());
  if (symlink(pts_.c_str(), tmp.c_str()) != 0 || rename(tmp.c_str(), opt_.link_path.c_str()) != 0) {
    *err = "cannot create the link " + opt_.link_path + ": " + strerror(errno);
    return false;
  }
  return true;
}

void SimHal::close_port() {
  if (master_ < 0) return;
  close(master_);
  master_ = -1;
  char target[256];
  ssize_t n = readlink(opt_.link_path.c_str(), target, sizeof target - 1);
  if (n > 0) {
    target[n] = 0;
    if (pts_ == target) unlink(opt_.link_path.c_str());
  }
}

size_t SimHal::read(uint8_t* buf, size_t max) {
  ssize_t n = ::read(master_, buf, max);
  if (n > 0) {
    host_present_ = true;
    return static_cast<size_t>(n);
  }
  if (n < 0 && errno == EIO) {
    host_present_ = false;  // no host has the port open
    out_.clear();
  } else {
    host_present_ = true;  // EAGAIN: open, nothing to read
  }
  return 0;
}

void SimHal::write(const char* line, size_t n) {
  if (reset_pending_ || !host_present_) return;  // as USB with no host: the line is lost
  std::string s(line, n);
  if (!opt_.reset_at.empty() && (s.rfind("$LOB,", 0) == 0 || s.rfind("$WAV,", 0) == 0)) {
    size_t c1 = s.find(',', 5), c2 = s.find(',', c1 + 1);
    long seq = strtol(s.substr(c1 + 1, c2 - c1 - 1).c_str(), nullptr, 10);
    if (opt_.reset_at.erase(seq)) {  // each once: half the line, then the watchdog bites
      out_ += s.substr(0, n / 2);
      reset_pending_ = true;
      flush();
      return;
    }
  }
  out_ += s;
  if (out_.size() > 65536) out_.erase(0, out_.size() - 65536);
  flush();
}

void SimHal::flush() {
  while (!out_.empty() && master_ >= 0) {
    ssize_t k = ::write(master_, out_.data(), out_.size());
    if (k > 0) {
      out_.erase(0, static_cast<size_t>(k));
      continue;
    }
    if (k < 0 && errno == EIO) {
      host_present_ = false;
      out_.clear();
    }
    return;  // EAGAIN: the pty buffer is full, try again later
  }
}

// ----------------------------------------------------------------------------------------------
// Motion
// ----------------------------------------------------------------------------------------------

void SimHal::update(Motor& m) {
  if (!m.active) return;
  double elapsed_s = (now_us() - m.t0_us) * 1e-6;
  int64_t dist = m.to - m.from;
  int sign = dist >= 0 ? 1 : -1;
  int64_t done = static_cast<int64_t>(m.rate * elapsed_s);
  bool arrived = done >= std::llabs(dist);
  if (arrived) done = std::llabs(dist);
  int64_t p = m.from + sign * done;
  if (m.stop_on_switch && sign == m.dir_to_switch && closed(m, p)) {  // the switch ends the move where it closed
    p = closed(m, m.from) ? m.from : m.switch_phys;
    arrived = true;
  }
  m.phys = p;
  if (arrived) m.active = false;
}

void SimHal::move(Axis a, int32_t target, uint32_t steps_per_s, bool stop_on_switch) {
  Motor& m = motor_[static_cast<int>(a)];
  update(m);
  m.from = m.phys;
  m.to = target + m.offset;
  m.rate = steps_per_s > 0 ? steps_per_s : 1;
  m.t0_us = now_us();
  m.stop_on_switch = stop_on_switch;
  m.active = m.to != m.from;
}

bool SimHal::moving(Axis a) {
  Motor& m = motor_[static_cast<int>(a)];
  update(m);
  return m.active;
}

void SimHal::stop(Axis a) {
  Motor& m = motor_[static_cast<int>(a)];
  update(m);
  m.active = false;
}

int32_t SimHal::position(Axis a) {
  Motor& m = motor_[static_cast<int>(a)];
  update(m);
  return static_cast<int32_t>(m.phys - m.offset);
}

void SimHal::set_position(Axis a, int32_t steps) {
  Motor& m = motor_[static_cast<int>(a)];
  update(m);
  m.offset = m.phys - steps;
}

bool SimHal::home_switch(Axis a) {
  Motor& m = motor_[static_cast<int>(a)];
  update(m);
  return closed(m, m.phys);
}

double SimHal::units(Axis a) const {
  const rig::AxisConfig& ac = cfg_.axis[static_cast<int>(a)];
  return static_cast<double>(motor_[static_cast<int>(a)].phys) * ac.den / ac.num;
}

int32_t SimHal::temperature_cC() {
  return static_cast<int32_t>(std::lround(opt_.temperature_c * 100.0));  // still air, a steady sensor
}

void SimHal::warn_once(const std::string& what) {
  if (warned_.insert(what).second) fprintf(stderr, "rig-sim: warning: %s\n", what.c_str());
}

// ----------------------------------------------------------------------------------------------
// Microphone, front end and ADC
// ----------------------------------------------------------------------------------------------

bool SimHal::acquire(const rig::BurstRequest& req, uint16_t* samples) {
  if (req.n_total > rig::kMaxSamples) return false;
  for (Motor& m : motor_) update(m);
  // The noise of an acquisition is a function of (seed, input, gain, axis positions, how many
  // acquisitions were taken there before): a point measured again after a reset, an abort or a
  // lost line repeats its values, so a capture does not depend on when faults happened.
  uint64_t key = 1469598103934665603ull;
  auto mix = [&key](uint64_t v) { key = (key ^ v) * 1099511628211ull; };
  mix(static_cast<uint64_t>(input_));
  mix(gain_);
  for (const Motor& m : motor_) mix(static_cast<uint64_t>(m.phys));
  visit_count_ = key == visit_key_ ? visit_count_ + 1 : 0;
  visit_key_ = key;
  std::seed_seq seq{static_cast<uint32_t>(opt_.seed), static_cast<uint32_t>(key), static_cast<uint32_t>(key >> 32),
                    static_cast<uint32_t>(visit_count_)};
  std::mt19937_64 rng(seq);
  std::normal_distribution<double> gauss(0.0, 1.0);  // local: a shared one caches draws across engines
  double f = req.freq_hz, fs = rig::kSpp * f, w = 2 * M_PI * f;
  if (std::fabs(f - truth_.freq_hz) > 0.5)
    warn_once("the truth table is for " + std::to_string(truth_.freq_hz) + " Hz, the scan drives " +
              std::to_string(f) + " Hz; using the table as it is");
  double amp = 0, lag = 0, tof = 1.0;
  bool have;
  if (input_ == rig::MicInput::Lobe) {
    have = truth_.lobe.at(units(Axis::Turntable), &amp, &lag, &tof);
    if (!have) warn_once("turntable angle outside the truth table's lobe: no signal there");
  } else {
    have = truth_.wave.at(units(Axis::StageX), &amp, &lag, &tof);
    if (std::fabs(units(Axis::StageZ) - truth_.wave_z_um) > 20.0) {
      warn_once("stage z differs from the truth table's wave z: no signal there");
      have = false;
    }
    if (!have) warn_once("stage position outside the truth table's wave: no signal there");
  }
  if (!have) amp = 0;
  // this burst: amplitude and phase jitter of the air path
  double a = amp * (1.0 + opt_.amp_jitter * gauss(rng));
  double phi = lag + opt_.phase_jitter_deg * M_PI / 180.0 * gauss(rng);
  // the front end: gain, the anti-alias filter's response at the carrier and its group delay
  const rig::Calibration& cal = cfg_.cal;
  rig::Cplx h = rig::butterworth4(f, cal.aa_cutoff_hz);
  double h_mag = std::hypot(h.re, h.im), h_lag = rig::aa_lag_rad(f, cal.aa_cutoff_hz);
  double gd = rig::aa_group_delay_s(f, cal.aa_cutoff_hz);
  double gain = cal.preamp_gain * cal.pga_gain[gain_];
  double counts_per_uV = gain / cal.adc_uV_per_count;
  double tau = opt_.tau_periods / f, t_burst = req.cycles / f;
  double top = 1.0 - std::exp(-t_burst / tau);
  for (uint32_t k = 0; k < req.n_total; ++k) {
    double t = (static_cast<double>(k) - req.n_pre) / fs;
    double u = t - tof - gd;
    double env = u <= 0 ? 0.0 : (u < t_burst ? 1.0 - std::exp(-u / tau) : top * std::exp(-(u - t_burst) / tau));
    double s_uV = a * h_mag * env * std::cos(w * t - phi - h_lag) + opt_.noise_uV * gauss(rng);
    double code = std::round(2048.0 + s_uV * counts_per_uV);
    samples[k] = static_cast<uint16_t>(code < 0 ? 0 : (code > 4095 ? 4095 : code));
  }
  return true;
}

}  // namespace sim
