// Shim (see Arduino.h): the SPI API of Teensyduino used by the HAL.
#pragma once
#include <stdint.h>
#define MSBFIRST 1
#define SPI_MODE0 0x00
class SPISettings {
 public:
  SPISettings(uint32_t clock, uint8_t bit_order, uint8_t data_mode);
};
class SPIClass {
 public:
  void begin();
  void beginTransaction(SPISettings settings);
  uint8_t transfer(uint8_t data);
  void endTransaction();
};
extern SPIClass SPI;
