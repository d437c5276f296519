// Reference rig firmware, protocol v1 (docs/rig.md): Teensy 4.1 sketch.
// Arduino IDE + Teensyduino: open this folder, board "Teensy 4.1", USB type "Serial", upload.
// PlatformIO: `pio run -e teensy41 -t upload` in firmware/.
// Your rig's mechanics, range and front-end calibration: edit `configure()` below.
#include <Arduino.h>

#include "src/core/rig.h"
#include "src/teensy41/teensy41_hal.h"

namespace {

rig::RigConfig configure() {
  rig::RigConfig c = rig::default_config();
  c.rig_id = "DL-RIG-0001";        // label on the box; the capture files record it
  c.cal.lobe_range_m = 1.000;      // measured turntable axis -> microphone (docs/rig.md, Calibration)
  // c.cal.gain_error[k] = ...;    // measured PGA steps (docs/rig.md, Calibration)
  return c;
}

rig::Teensy41Hal g_hal;
const rig::RigConfig g_cfg = configure();
rig::Rig g_rig(g_hal, g_cfg);

}  // namespace

void setup() {
  g_hal.begin();
  g_rig.begin();
}

void loop() { g_rig.poll(); }
