// The rig firmware proper: protocol v1 state machine, homing, scans and point measurements.
// Board-independent: all hardware access goes through `Hal` (hal.h). The board's loop() and the
// host simulator both call `Rig::poll()` over and over; it never blocks for longer than one burst
// capture (a few ms), so heartbeats, ABORT and STAT are served during homing and scans.
#pragma once

#include <stddef.h>
#include <stdint.h>

#include "frontend.h"
#include "hal.h"
#include "lockin.h"
#include "protocol.h"

namespace rig {

// One motion axis: position [unit] = steps * den / num (unit: mdeg for the turntable, um for
// the stage), travel limits, the home switch's position and the homing speeds.
struct AxisConfig {
  int32_t num, den;           // steps per `den` units: steps = round(units * num / den)
  int32_t min_units, max_units;
  int32_t home_units;         // where the home switch closes (outside [min, max])
  int32_t backoff_units;      // how far to back off the switch before the slow approach
  int32_t park_units;         // where the axis goes after homing
  uint32_t fast_sps, slow_sps, move_sps;  // homing seek, homing approach, scan moves [steps/s]
};

constexpr uint32_t kMaxSamples = 8192;   // ADC samples per burst (window at fs = 8 f)
constexpr uint32_t kMinFreqHz = 10000, kMaxFreqHz = 100000;  // fs = 8 f <= 800 kS/s
constexpr int32_t kMaxPoints = 100000, kMaxAvg = 1000, kMaxCycles = 1000;

struct RigConfig {
  const char* fw_version;
  const char* rig_id;
  AxisConfig axis[kNumAxes];
  Calibration cal;
  uint32_t heartbeat_ms;       // silence before a heartbeat (protocol: 1 s)
  uint32_t settle_ms;          // after a move, before the first burst (vibration dies down)
  uint32_t burst_period_ms;    // burst repetition (echoes and ringing die down)
  uint16_t n_pre;              // ADC samples before each burst (DC and noise)
};

// The reference rig's mechanics and front end (docs/rig.md, bill of materials).
RigConfig default_config();

int32_t units_to_steps(const AxisConfig& a, int32_t units);

class Rig {
 public:
  Rig(Hal& hal, const RigConfig& cfg);
  // After a reset: pick a boot id, send BOOT. The axes are not homed.
  void begin();
  // Serve input, advance homing or the scan by one bounded step, send a heartbeat when due.
  // Returns how long [us] the caller may sleep before the next call (input wakes it earlier).
  uint32_t poll();

  bool homed() const { return homed_; }

 private:
  enum class Mode : uint8_t { Idle, Homing, Scan };
  enum class HomePhase : uint8_t { Start, Clear, Seek, Backoff, Approach, Park, Next };
  enum class ScanPhase : uint8_t { MoveZ, Move, Settle, Range, Average, Report };

  void send(const char* fmt, ...)
#if defined(__GNUC__)
      __attribute__((format(printf, 2, 3)))
#endif
      ;
  void send_err(ErrCode code, const char* detail);
  void send_hbt();
  void handle_line(const char* line, size_t n);
  void handle(const Command& c);
  void start_scan(const Command& c);
  void end_scan(const char* status);
  uint32_t step_homing();
  uint32_t step_scan();
  bool burst(bool ranging);
  void finish_point();
  double speed_of_sound() const;
  double counts_to_uV() const;
  double predicted_arrival_s(int32_t seq) const;
  uint32_t window_samples(int32_t seq) const;
  Axis scan_axis() const { return scan_.type == CmdType::Lobe ? Axis::Turntable : Axis::StageX; }
  int32_t position_units(int32_t seq) const { return scan_.start + seq * scan_.step; }
  bool due(uint32_t t_us) const { return static_cast<int32_t>(now_ - t_us) >= 0; }

  Hal& hal_;
  const RigConfig& cfg_;
  LineReader reader_;
  uint32_t now_ = 0, last_tx_ = 0;
  uint64_t uptime_us_ = 0;
  uint16_t boot_id_ = 0;
  bool homed_ = false;
  Mode mode_ = Mode::Idle;

  // homing
  int home_axis_ = 0;           // index into the homing order
  HomePhase home_phase_ = HomePhase::Start;
  bool home_failed_ = false;

  // scan
  Command scan_{};
  int32_t next_seq_ = 0, sent_ = 0, last_scan_ = 0, last_next_seq_ = 0;
  ScanPhase phase_ = ScanPhase::Move;
  uint32_t wait_until_ = 0;
  uint8_t gain_ = 0;
  int ranging_tries_ = 0;
  int bursts_ = 0;
  int gate_start_ = 0, gate_len_ = 0;
  uint32_t n_window_ = 0;
  double amp_sum_ = 0, amp_sum2_ = 0;
  int32_t temp_cC_ = 0;
  double noise_ = 0;                  // rms noise of one ADC sample of the last burst, counts
  double h_mag_ = 1, h_lag_rad_ = 0;  // front end's response at the carrier
  double gd_s_ = 0;                   // front end's group delay plus the driver's delay
};

}  // namespace rig
