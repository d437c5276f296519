// Teensy 4.1 hardware seam (Teensyduino core). Compiled for Cortex-M7 by `make -C firmware
// board-check` against the declarations in firmware/shim/ (the Teensyduino core itself is not in
// the package registries); on a lab bench it builds with the Arduino IDE + Teensyduino or
// PlatformIO (firmware/platformio.ini).
//
// Design: the steppers run from a 40 kHz IntervalTimer (a DDA per axis with a linear speed ramp);
// a burst is cycle-counted with interrupts off: the drive pins toggle and the ADC converts at
// exact multiples of 1/(8 f) of the ARM cycle counter, so the drive and the samples share one
// clock (the lock-in's phase reference) and the jitter is a few CPU cycles (ns).
#include "teensy41_hal.h"

#include <Arduino.h>
#include <SPI.h>
#include <Wire.h>

#include "../core/lockin.h"

namespace rig {

namespace {

struct Stepper {
  volatile int32_t pos = 0;
  volatile int32_t target = 0;
  volatile uint32_t rate_max = 0;   // steps/s
  volatile uint32_t rate = 0;       // current steps/s (ramped)
  volatile uint32_t acc = 0;        // DDA accumulator
  volatile bool active = false;
  volatile bool stop_on_switch = false;
  volatile bool pulse_high = false;
};

Stepper g_axes[kNumAxes];
Teensy41Hal* g_hal = nullptr;
IntervalTimer g_step_timer;
constexpr uint32_t kAccel = 40000;        // steps/s^2
constexpr uint8_t kTmp117 = 0x48;         // TMP117 air temperature sensor, I2C address
const uint8_t kPgaGainCode[6] = {0, 1, 2, 4, 6, 7};  // MCP6S22 codes for gains 1, 2, 4, 8, 16, 32

void step_tick() {
  if (g_hal) g_hal->step_isr();
}

}  // namespace

Teensy41Hal::Teensy41Hal(const Pins& pins) : pins_(pins) {}

void Teensy41Hal::begin() {
  // why we started (SRC reset status register; write 1s to clear)
  uint32_t srsr = SRC_SRSR;
  SRC_SRSR = srsr;
  if (srsr & (1u << 4) || srsr & (1u << 7)) reason_ = ResetReason::Watchdog;
  else if (srsr & (1u << 3)) reason_ = ResetReason::External;
  else if (srsr & 1u) reason_ = ResetReason::PowerOn;
  else reason_ = ResetReason::Unknown;

  ARM_DEMCR |= ARM_DEMCR_TRCENA;  // cycle counter for the burst timing
  ARM_DWT_CTRL |= ARM_DWT_CTRL_CYCCNTENA;

  for (int a = 0; a < kNumAxes; ++a) {
    if (!pins_.fitted[a]) continue;
    pinMode(pins_.step[a], OUTPUT);
    pinMode(pins_.dir[a], OUTPUT);
    pinMode(pins_.enable[a], OUTPUT);
    digitalWriteFast(pins_.enable[a], HIGH);  // drivers off until homing
    pinMode(pins_.home[a], INPUT_PULLUP);
  }
  pinMode(pins_.drive_a, OUTPUT);
  pinMode(pins_.drive_b, OUTPUT);
  digitalWriteFast(pins_.drive_a, LOW);
  digitalWriteFast(pins_.drive_b, LOW);
  pinMode(pins_.pga_cs, OUTPUT);
  digitalWriteFast(pins_.pga_cs, HIGH);
  SPI.begin();
  Wire.begin();
  Wire.setClock(400000);
  // ADC1: 12 bits, no hardware averaging, high-speed conversion, software trigger
  analogReadResolution(12);
  analogReadAveraging(1);
  analogRead(pins_.adc_pin);  // the core configures the pin's mux
  ADC1_CFG = ADC_CFG_MODE(2) | ADC_CFG_ADICLK(0) | ADC_CFG_ADIV(0) | ADC_CFG_ADSTS(0) | ADC_CFG_ADHSC;
  Serial.begin(115200);  // USB: the rate is ignored
  g_hal = this;
  g_step_timer.begin(step_tick, 1000000.0f / kStepTickHz);
  // watchdog (WDOG1): 2 s; poll() kicks it, a hung firmware resets and says WDT in BOOT
  WDOG1_WMCR = 0;
  WDOG1_WCR = WDOG_WCR_WDE | WDOG_WCR_WT(3) | WDOG_WCR_SRS | WDOG_WCR_WDA;
}

uint32_t Teensy41Hal::micros() { return ::micros(); }

uint32_t Teensy41Hal::entropy() {
  uint32_t x = ARM_DWT_CYCCNT;
  for (int i = 0; i < 16; ++i) x = (x * 2654435761u) ^ static_cast<uint32_t>(analogRead(pins_.adc_pin));
  return x;
}

void Teensy41Hal::kick_watchdog() {
  WDOG1_WSR = 0x5555;
  WDOG1_WSR = 0xAAAA;
}

size_t Teensy41Hal::read(uint8_t* buf, size_t max) {
  size_t n = 0;
  while (n < max && Serial.available() > 0) buf[n++] = static_cast<uint8_t>(Serial.read());
  return n;
}

void Teensy41Hal::write(const char* line, size_t n) {
  // no host with the port open, or its buffer full: drop the line (the host re-requests it)
  if (!Serial.dtr() || static_cast<size_t>(Serial.availableForWrite()) < n) return;
  Serial.write(reinterpret_cast<const uint8_t*>(line), n);
  Serial.send_now();
}

// --- motion ---------------------------------------------------------------------------------

void Teensy41Hal::step_isr() {
  for (int a = 0; a < kNumAxes; ++a) {
    Stepper& s = g_axes[a];
    if (s.pulse_high) {  // end the previous step pulse (25 us wide)
      digitalWriteFast(pins_.step[a], LOW);
      s.pulse_high = false;
    }
    if (!s.active) continue;
    if (s.stop_on_switch && digitalReadFast(pins_.home[a])) {
      s.active = false;
      continue;
    }
    int32_t left = s.target - s.pos;
    if (left == 0) {
      s.active = false;
      continue;
    }
    // linear ramp: accelerate to rate_max, decelerate when the remaining steps need it
    uint32_t remaining = static_cast<uint32_t>(left > 0 ? left : -left);
    uint64_t stop_dist = static_cast<uint64_t>(s.rate) * s.rate / (2 * kAccel);
    uint32_t dv = kAccel / kStepTickHz + 1;
    if (stop_dist >= remaining && s.rate > 200) s.rate -= dv;
    else if (s.rate < s.rate_max) s.rate = (s.rate + dv > s.rate_max) ? s.rate_max : s.rate + dv;
    s.acc += s.rate;
    if (s.acc >= kStepTickHz) {
      s.acc -= kStepTickHz;
      digitalWriteFast(pins_.dir[a], left > 0 ? HIGH : LOW);
      digitalWriteFast(pins_.step[a], HIGH);
      s.pulse_high = true;
      s.pos += left > 0 ? 1 : -1;
    }
  }
}

void Teensy41Hal::enable(Axis a, bool on) { digitalWriteFast(pins_.enable[static_cast<int>(a)], on ? LOW : HIGH); }

void Teensy41Hal::move(Axis a, int32_t target, uint32_t steps_per_s, bool stop_on_switch) {
  Stepper& s = g_axes[static_cast<int>(a)];
  noInterrupts();
  s.target = target;
  s.rate_max = steps_per_s < kStepTickHz / 2 ? steps_per_s : kStepTickHz / 2;
  s.rate = 200 < s.rate_max ? 200 : s.rate_max;
  s.acc = 0;
  s.stop_on_switch = stop_on_switch;
  s.active = target != s.pos;
  interrupts();
}

bool Teensy41Hal::moving(Axis a) { return g_axes[static_cast<int>(a)].active; }

void Teensy41Hal::stop(Axis a) { g_axes[static_cast<int>(a)].active = false; }

int32_t Teensy41Hal::position(Axis a) { return g_axes[static_cast<int>(a)].pos; }

void Teensy41Hal::set_position(Axis a, int32_t steps) {
  noInterrupts();
  g_axes[static_cast<int>(a)].pos = steps;
  g_axes[static_cast<int>(a)].target = steps;
  interrupts();
}

bool Teensy41Hal::home_switch(Axis a) { return digitalReadFast(pins_.home[static_cast<int>(a)]) != 0; }

// --- acoustics ------------------------------------------------------------------------------

void Teensy41Hal::select(MicInput in, uint8_t gain_index) {
  uint8_t ch = static_cast<uint8_t>(in);
  if (ch == input_ && gain_index == gain_) return;
  SPI.beginTransaction(SPISettings(10000000, MSBFIRST, SPI_MODE0));
  digitalWriteFast(pins_.pga_cs, LOW);
  SPI.transfer(0x41);  // MCP6S22: write the channel register
  SPI.transfer(ch);
  digitalWriteFast(pins_.pga_cs, HIGH);
  delayNanoseconds(100);
  digitalWriteFast(pins_.pga_cs, LOW);
  SPI.transfer(0x40);  // write the gain register
  SPI.transfer(kPgaGainCode[gain_index < 6 ? gain_index : 5]);
  digitalWriteFast(pins_.pga_cs, HIGH);
  SPI.endTransaction();
  input_ = ch;
  gain_ = gain_index;
  delayMicroseconds(20);  // PGA settling
}

bool Teensy41Hal::acquire(const BurstRequest& req, uint16_t* samples) {
  uint32_t fs = kSpp * req.freq_hz;
  if (fs > 800000 || req.n_total > 8192) return false;  // the ADC converts in ~0.8 us at 12 bits
  // sample instant k is at t0 + k * cycles_per_sample (F_CPU_ACTUAL / fs, in 1/256 cycles)
  uint64_t per = (static_cast<uint64_t>(F_CPU_ACTUAL) << 8) / fs;
  int32_t drive_start = req.n_pre - 2;                 // the square wave is high from -T/4 ...
  int32_t drive_end = req.n_pre + kSpp * req.cycles - 2;  // ... over whole cycles
  noInterrupts();
  uint32_t t0 = ARM_DWT_CYCCNT + 2000;
  for (uint32_t k = 0; k < req.n_total; ++k) {
    uint32_t due = t0 + static_cast<uint32_t>((per * k) >> 8);
    while (static_cast<int32_t>(ARM_DWT_CYCCNT - due) < 0) {
    }
    int32_t j = static_cast<int32_t>(k) - drive_start;  // drive phase: 8 samples per period
    if (static_cast<int32_t>(k) >= drive_start && static_cast<int32_t>(k) < drive_end) {
      bool high = (j % kSpp) < kSpp / 2;
      digitalWriteFast(pins_.drive_a, high ? HIGH : LOW);
      digitalWriteFast(pins_.drive_b, high ? LOW : HIGH);
    } else {
      digitalWriteFast(pins_.drive_a, LOW);
      digitalWriteFast(pins_.drive_b, LOW);
    }
    ADC1_HC0 = pins_.adc_channel;  // start a conversion now
    while (!(ADC1_HS & ADC_HS_COCO0)) {
    }
    samples[k] = static_cast<uint16_t>(ADC1_R0);
  }
  digitalWriteFast(pins_.drive_a, LOW);
  digitalWriteFast(pins_.drive_b, LOW);
  interrupts();
  return true;
}

int32_t Teensy41Hal::temperature_cC() {
  Wire.beginTransmission(kTmp117);
  Wire.write(0x00);  // temperature register: 7.8125 m degC per LSB
  if (Wire.endTransmission(false) == 0 && Wire.requestFrom(kTmp117, static_cast<uint8_t>(2)) == 2) {
    int16_t raw = static_cast<int16_t>((Wire.read() << 8) | Wire.read());
    last_temp_cC_ = (static_cast<int32_t>(raw) * 25 + 16) / 32;  // 0.78125 cC per LSB
  }
  return last_temp_cC_;
}

}  // namespace rig
