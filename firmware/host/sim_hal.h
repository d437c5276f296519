// Simulated rig hardware for the host build: the pseudo-terminal is the USB serial port, stepper
// axes move in (scaled) time and close their home switches, and the microphone's ADC samples are
// synthesised from a ground-truth table of complex pressures (written by the project's Python
// ground-truth code, firmware/tools/truth_table.py) with noise, burst envelopes, the front end's
// gain and anti-alias filter, 12-bit quantisation and clipping, so the lock-in really runs.
#pragma once

#include <stdint.h>

#include <random>
#include <set>
#include <string>
#include <vector>

#include "../rig_firmware/src/core/hal.h"
#include "../rig_firmware/src/core/rig.h"

namespace sim {

// Complex pressure [uV at the microphone's output] and arrival time along one scan coordinate,
// exp(-i w t) convention: the received carrier is |p| cos(w t - arg p), so arg p is the lag.
struct Table {
  std::vector<double> pos, amp, lag_rad, tof_s;  // lag unwrapped along pos
  bool at(double x, double* amp_out, double* lag_out, double* tof_out) const;
};

struct Truth {
  double freq_hz = 0;
  Table lobe;          // pos: angle [mdeg]
  Table wave;          // pos: x [um] on the line z = wave_z_um
  double wave_z_um = 0;
  bool load(const std::string& path, std::string* err);
};

struct Options {
  std::string truth_path, link_path, rig_id = "DL-SIM-0001";
  double speed = 50.0;            // simulated time runs this much faster than real time
  uint64_t seed = 1;
  double temperature_c = 21.0;
  double noise_uV = 60.0;         // white noise per ADC sample, referred to the microphone output
  double amp_jitter = 0.005;      // relative amplitude jitter per burst (drive, air)
  double phase_jitter_deg = 0.3;  // carrier phase jitter per burst (air turbulence)
  double tau_periods = 1.0;       // transducer + microphone envelope time constant, carrier periods
  double lobe_range_m = 1.0;
  std::set<long> reset_at;        // seqs whose point line is cut in half by a watchdog reset
};

class SimHal : public rig::Hal {
 public:
  SimHal(const Options& opt, const Truth& truth, const rig::RigConfig& cfg);
  ~SimHal() override;

  bool open_port(std::string* err);  // pty in raw mode + stable symlink
  void close_port();
  int fd() const { return master_; }
  bool host_present() const { return host_present_; }
  void flush();
  bool reset_pending() const { return reset_pending_; }
  void rebooted() { reset_pending_ = false; reason_ = rig::ResetReason::Watchdog; }

  // Hal
  uint32_t micros() override;
  rig::ResetReason reset_reason() override { return reason_; }
  uint32_t entropy() override { return static_cast<uint32_t>(rng_()); }
  void kick_watchdog() override {}
  size_t read(uint8_t* buf, size_t max) override;
  void write(const char* line, size_t n) override;
  bool fitted(rig::Axis) override { return true; }
  void enable(rig::Axis, bool) override {}
  void move(rig::Axis a, int32_t target, uint32_t steps_per_s, bool stop_on_switch) override;
  bool moving(rig::Axis a) override;
  void stop(rig::Axis a) override;
  int32_t position(rig::Axis a) override;
  void set_position(rig::Axis a, int32_t steps) override;
  bool home_switch(rig::Axis a) override;
  void select(rig::MicInput in, uint8_t gain_index) override {
    input_ = in;
    gain_ = gain_index;
  }
  bool acquire(const rig::BurstRequest& req, uint16_t* samples) override;
  int32_t temperature_cC() override;

 private:
  struct Motor {
    int64_t phys = 0;       // physical position, steps (0: the axis' zero)
    int64_t offset = 0;     // firmware counter = phys - offset
    bool active = false;
    int64_t from = 0, to = 0;
    double rate = 1;        // steps/s
    uint64_t t0_us = 0;     // virtual start time
    bool stop_on_switch = false;
    int64_t switch_phys = 0;
    int dir_to_switch = -1;
  };
  void update(Motor& m);
  bool closed(const Motor& m, int64_t phys) const {
    return m.dir_to_switch > 0 ? phys >= m.switch_phys : phys <= m.switch_phys;
  }
  double units(rig::Axis a) const;  // physical position in axis units
  uint64_t now_us();
  void warn_once(const std::string& what);

  Options opt_;
  const Truth& truth_;
  const rig::RigConfig& cfg_;
  Motor motor_[rig::kNumAxes];
  std::mt19937_64 rng_;
  uint64_t real0_ns_ = 0;
  int master_ = -1;
  std::string pts_;
  bool host_present_ = false;
  std::string out_;
  bool reset_pending_ = false;
  rig::ResetReason reason_ = rig::ResetReason::PowerOn;
  rig::MicInput input_ = rig::MicInput::Lobe;
  uint8_t gain_ = 0;
  std::set<std::string> warned_;
  uint64_t visit_key_ = 0;    // input, gain and axis positions of the last acquisition
  uint64_t visit_count_ = 0;  // acquisitions since they last changed
};

}  // namespace sim
