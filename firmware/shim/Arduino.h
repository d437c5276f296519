// Minimal declarations of the Teensyduino core API that firmware/rig_firmware uses, for
// `make -C firmware board-check` (compile only, for Cortex-M7): the Teensyduino core is not in
// the package registries. Names, signatures and register addresses follow Teensyduino 1.59
// (cores/teensy4: core_pins.h, imxrt.h, usb_serial.h, IntervalTimer.h). Nothing here is linked.
#pragma once

#include <stddef.h>
#include <stdint.h>

#define HIGH 1
#define LOW 0
#define INPUT 0
#define OUTPUT 1
#define INPUT_PULLUP 2

extern "C" volatile uint32_t F_CPU_ACTUAL;

void pinMode(uint8_t pin, uint8_t mode);
void digitalWriteFast(uint8_t pin, uint8_t val);
uint8_t digitalReadFast(uint8_t pin);
uint32_t micros(void);
uint32_t millis(void);
void delayMicroseconds(uint32_t usec);
void delayNanoseconds(uint32_t nsec);
int analogRead(uint8_t pin);
void analogReadResolution(unsigned int bits);
void analogReadAveraging(unsigned int num);

#define noInterrupts() __asm__ volatile("CPSID i" ::: "memory")
#define interrupts() __asm__ volatile("CPSIE i" ::: "memory")

// Cortex-M7 debug: cycle counter
#define ARM_DEMCR (*(volatile uint32_t*)0xE000EDFC)
#define ARM_DEMCR_TRCENA (1u << 24)
#define ARM_DWT_CTRL (*(volatile uint32_t*)0xE0001000)
#define ARM_DWT_CTRL_CYCCNTENA (1u << 0)
#define ARM_DWT_CYCCNT (*(volatile uint32_t*)0xE0001004)

// i.MX RT1062: system reset controller, ADC1, watchdog 1
#define SRC_SRSR (*(volatile uint32_t*)0x400F8008)
#define ADC1_HC0 (*(volatile uint32_t*)0x400C4000)
#define ADC1_HS (*(volatile uint32_t*)0x400C4020)
#define ADC1_R0 (*(volatile uint32_t*)0x400C4024)
#define ADC1_CFG (*(volatile uint32_t*)0x400C4044)
#define ADC_HS_COCO0 (1u << 0)
#define ADC_CFG_ADICLK(n) (((n) & 0x03u) << 0)
#define ADC_CFG_MODE(n) (((n) & 0x03u) << 2)
#define ADC_CFG_ADIV(n) (((n) & 0x03u) << 5)
#define ADC_CFG_ADSTS(n) (((n) & 0x03u) << 8)
#define ADC_CFG_ADHSC (1u << 10)
#define WDOG1_WCR (*(volatile uint16_t*)0x400B8000)
#define WDOG1_WSR (*(volatile uint16_t*)0x400B8002)
#define WDOG1_WMCR (*(volatile uint16_t*)0x400B8008)
#define WDOG_WCR_WDE (1u << 2)
#define WDOG_WCR_SRS (1u << 4)
#define WDOG_WCR_WDA (1u << 5)
#define WDOG_WCR_WT(n) (((n) & 0xFFu) << 8)

class usb_serial_class {
 public:
  void begin(long baud);
  int available();
  int read();
  size_t write(const uint8_t* buf, size_t n);
  int availableForWrite();
  int dtr();
  void send_now();
};
extern usb_serial_class Serial;

class IntervalTimer {
 public:
  bool begin(void (*funct)(), float microseconds);
  void end();
};
