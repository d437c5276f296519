// Teensy 4.1 (NXP i.MX RT1062, Cortex-M7 at 600 MHz) implementation of the rig's hardware seam.
// Pin map and parts: docs/rig.md ("Wiring"). Only this file and teensy41_hal.cpp touch pins.
#pragma once

#include "../core/hal.h"

namespace rig {

struct Pins {
  // step, dir, enable (active low), home switch (normally closed to GND, input pull-up: HIGH = at
  // the switch or a broken wire, so a cut cable stops homing instead of crashing the axis)
  uint8_t step[kNumAxes] = {2, 6, 24};
  uint8_t dir[kNumAxes] = {3, 7, 25};
  uint8_t enable[kNumAxes] = {4, 8, 26};
  uint8_t home[kNumAxes] = {5, 9, 27};
  bool fitted[kNumAxes] = {true, true, true};
  uint8_t drive_a = 28, drive_b = 29;  // TC4427A inputs: the transducer is driven in antiphase
  uint8_t pga_cs = 10;                 // MCP6S22 on SPI (MOSI 11, SCK 13)
  uint8_t adc_pin = 14;                // A0 = ADC1 channel 7: the PGA's output, biased at 1.65 V
  uint8_t adc_channel = 7;
};

class Teensy41Hal : public Hal {
 public:
  explicit Teensy41Hal(const Pins& pins = Pins());
  void begin();  // pins, ADC, SPI, I2C, step timer, watchdog

  uint32_t micros() override;
  ResetReason reset_reason() override { return reason_; }
  uint32_t entropy() override;
  void kick_watchdog() override;
  size_t read(uint8_t* buf, size_t max) override;
  void write(const char* line, size_t n) override;
  bool fitted(Axis a) override { return pins_.fitted[static_cast<int>(a)]; }
  void enable(Axis a, bool on) override;
  void move(Axis a, int32_t target, uint32_t steps_per_s, bool stop_on_switch) override;
  bool moving(Axis a) override;
  void stop(Axis a) override;
  int32_t position(Axis a) override;
  void set_position(Axis a, int32_t steps) override;
  bool home_switch(Axis a) override;
  void select(MicInput in, uint8_t gain_index) override;
  bool acquire(const BurstRequest& req, uint16_t* samples) override;
  int32_t temperature_cC() override;

  void step_isr();  // called by the step timer at kStepTickHz

  static constexpr uint32_t kStepTickHz = 40000;

 private:
  Pins pins_;
  ResetReason reason_ = ResetReason::Unknown;
  int32_t last_temp_cC_ = 2000;
  uint8_t input_ = 0xFF, gain_ = 0xFF;
};

}  // namespace rig
