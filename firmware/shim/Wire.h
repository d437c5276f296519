// Shim (see Arduino.h): the Wire (I2C) API of Teensyduino used by the HAL.
#pragma once
#include <stddef.h>
#include <stdint.h>
class TwoWire {
 public:
  void begin();
  void setClock(uint32_t frequency);
  void beginTransmission(uint8_t address);
  size_t write(uint8_t data);
  uint8_t endTransmission(bool send_stop = true);
  uint8_t requestFrom(uint8_t address, uint8_t quantity);
  int read();
};
extern TwoWire Wire;
