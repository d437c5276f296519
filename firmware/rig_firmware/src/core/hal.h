// Hardware seam of the rig firmware: everything that touches a pin or a peripheral.
//
// The protocol and scan code (rig.cpp, protocol.cpp, lockin.cpp) talk to the hardware only through
// this interface, so the same code runs on the board (src/teensy41/teensy41_hal.cpp) and on a
// Linux host with a simulated turntable, stage and microphone (firmware/host/sim_hal.cpp).
//
// Conventions: positions are in motor (micro)steps of each axis, counted by the HAL; time is the
// firmware's monotonic clock in microseconds (wraps after 71 minutes: compare differences only).
#pragma once

#include <stddef.h>
#include <stdint.h>

namespace rig {

enum class Axis : uint8_t { Turntable = 0, StageX = 1, StageZ = 2 };
constexpr int kNumAxes = 3;

// Why the firmware (re)started; reported in BOOT.
enum class ResetReason : uint8_t { PowerOn, External, BrownOut, Watchdog, Unknown };

// Which microphone the front end listens to (the PGA's two inputs): the lobe rig's fixed
// microphone or the wavefront rig's microphone on the XY stage.
enum class MicInput : uint8_t { Lobe = 0, Wave = 1 };

// One captured burst: ADC samples taken at exactly `samples_per_period` per carrier period,
// clocked from the same timer as the drive. Sample k (0 <= k < n_total) is at time
// (k - n_pre) / fs from the drive's reference instant t = 0, where the drive's fundamental is
// cos(2 pi f t) (the square wave is centred on t = 0). Samples 0..n_pre-1 precede the drive.
struct BurstRequest {
  uint32_t freq_hz;          // carrier frequency
  uint16_t cycles;           // burst length in carrier cycles (the drive is off afterwards)
  uint16_t n_pre;            // samples before the drive starts (DC and noise estimate)
  uint32_t n_total;          // samples to take in all (n_pre + window)
};

class Hal {
 public:
  virtual ~Hal() = default;

  // --- clock, identity, watchdog
  virtual uint32_t micros() = 0;
  virtual ResetReason reset_reason() = 0;
  virtual uint32_t entropy() = 0;  // a few random bits (ADC noise, RNG peripheral) for boot_id
  virtual void kick_watchdog() = 0;

  // --- host link (USB serial). read() never blocks; write() queues a whole line (the HAL may
  // drop it when no host has the port open, as USB does).
  virtual size_t read(uint8_t* buf, size_t max) = 0;
  virtual void write(const char* line, size_t n) = 0;

  // --- motion (step/dir drivers). move() starts a move towards `target` (steps) at
  // `steps_per_s` and returns at once; with stop_on_switch the move ends early when the axis'
  // home switch closes. moving() polls; position() is the step counter; set_position() rebases it.
  virtual bool fitted(Axis a) = 0;
  virtual void enable(Axis a, bool on) = 0;
  virtual void move(Axis a, int32_t target, uint32_t steps_per_s, bool stop_on_switch) = 0;
  virtual bool moving(Axis a) = 0;
  virtual void stop(Axis a) = 0;
  virtual int32_t position(Axis a) = 0;
  virtual void set_position(Axis a, int32_t steps) = 0;
  virtual bool home_switch(Axis a) = 0;  // true while the switch is closed

  // --- acoustics. select() chooses the microphone input and the PGA gain step (index into the
  // calibration's gain table). acquire() fires one burst at the commanded frequency and cycles
  // and fills `samples` (12-bit ADC codes) as BurstRequest describes; it blocks for the capture
  // window (a few ms) and returns false if the request cannot be served (rate, buffer).
  virtual void select(MicInput in, uint8_t gain_index) = 0;
  virtual bool acquire(const BurstRequest& req, uint16_t* samples) = 0;

  // --- environment
  virtual int32_t temperature_cC() = 0;  // air temperature, hundredths of a degree Celsius
};

}  // namespace rig
