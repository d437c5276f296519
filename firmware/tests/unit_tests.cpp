// Unit tests of the board-independent firmware core: CRC and framing against the protocol's
// check values, strict parsing, the line reader's resynchronisation, the lock-in's amplitude and
// phase sign on synthetic bursts (a pure delay tau must read as a lag of 360 f tau), and the
// step conversions. `make -C firmware test`.
#include <math.h>
#include <stdio.h>
#include <string.h>

#include <initializer_list>

#include "../rig_firmware/src/core/frontend.h"
#include "../rig_firmware/src/core/lockin.h"
#include "../rig_firmware/src/core/protocol.h"
#include "../rig_firmware/src/core/rig.h"

static int g_failed = 0, g_checks = 0;
#define CHECK(cond)                                                  \
  do {                                                               \
    ++g_checks;                                                      \
    if (!(cond)) {                                                   \
      ++g_failed;                                                    \
      fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); \
    }                                                                \
  } while (0)

using namespace rig;

static ParseResult parse(const char* s) { return parse_line(s, strlen(s)); }

static void test_crc_and_framing() {
  CHECK(crc16(reinterpret_cast<const uint8_t*>("123456789"), 9) == 0x29B1);
  char line[kMaxLine + 1];
  size_t n = format_line(line, "HOME");
  CHECK(n == strlen("$HOME*3DF2\n") && strcmp(line, "$HOME*3DF2\n") == 0);  // the protocol's example
  ParseResult r = parse("$LOBE,7,80,181,-90000,1000,8,16,49400*20EE\n");
  CHECK(r.err == ErrCode::None && r.cmd.type == CmdType::Lobe && r.cmd.first_seq == 80 && r.cmd.start == -90000 &&
        r.cmd.freq_hz == 49400);
  CHECK(parse("$LOBE,7,80,181,-90000,1000,8,16,49400*20EF\n").err == ErrCode::BadCrc);
  CHECK(parse("$HOME*3DF2\r\n").err == ErrCode::Malformed);  // the reader strips "\r" before parse_line
  format_line(line, "LOBE,7,080,181,-90000,1000,8,16,49400");  // leading zero: not canonical
  CHECK(parse(line).err == ErrCode::BadArg);
  format_line(line, "LOBE,7,-0,181,-90000,1000,8,16,49400");
  CHECK(parse(line).err == ErrCode::BadArg);
  format_line(line, "LOBE,7,0,181");
  ParseResult few = parse(line);
  CHECK(few.err == ErrCode::BadArg && strcmp(few.detail, "LOBE") == 0);
  format_line(line, "FROB,1");
  CHECK(parse(line).err == ErrCode::BadCmd);
  format_line(line, "home");
  CHECK(parse(line).err == ErrCode::BadCmd);
  format_line(line, "HELLO,1");
  CHECK(parse(line).err == ErrCode::None && parse(line).cmd.proto == 1);
}

static void test_line_reader() {
  LineReader rd;
  // junk, a truncated line with a whole line glued on, "\r\n", an over-long line
  const char* stream = "xx\x01$LOB,7,80,-10$HOME*3DF2\r\n";
  int lines = 0;
  for (const char* p = stream; *p; ++p)
    if (rd.feed(static_cast<uint8_t>(*p))) {
      ++lines;
      CHECK(!rd.overflow() && strcmp(rd.line(), "$HOME*3DF2\n") == 0);
      CHECK(parse_line(rd.line(), rd.size()).err == ErrCode::None);
    }
  CHECK(lines == 1);
  int over = 0;
  rd.feed('$');
  for (int i = 0; i < 200; ++i)
    if (rd.feed('A')) over += rd.overflow() ? 1 : 100;
  CHECK(over == 1);
  CHECK(!rd.feed('\n'));  // the rest of the long line is dropped
  lines = 0;
  for (const char* p = "$STAT*"; *p; ++p) rd.feed(static_cast<uint8_t>(*p));
  char crc[8];
  snprintf(crc, sizeof crc, "%04X\n", crc16(reinterpret_cast<const uint8_t*>("STAT"), 4));
  for (const char* p = crc; *p; ++p) lines += rd.feed(static_cast<uint8_t>(*p)) ? 1 : 0;
  CHECK(lines == 1 && parse_line(rd.line(), rd.size()).cmd.type == CmdType::Stat);
}

// A burst at the ADC: amplitude A counts, delayed by tau, of `cycles` cycles (rectangular envelope).
static void synth(float* d, int n, double a, double tau_s, double f, int cycles) {
  double fs = kSpp * f;
  for (int k = 0; k < n; ++k) {
    double t = k / fs, u = t - tau_s;
    d[k] = (u >= 0 && u < cycles / f) ? static_cast<float>(a * cos(2 * kPi * f * (t - tau_s))) : 0.0f;
  }
}

static void test_lockin_sign_and_amplitude() {
  static float d[4096], env[4096];
  const double f = 40000.0;
  for (double tau_us : {100.0, 112.5, 131.3}) {
    synth(d, 4096, 500.0, tau_us * 1e-6, f, 16);
    envelope(d, 4096, env);
    Arrival a = find_arrival(env, 4096, 1.0);
    CHECK(a.found);
    double t_arr = a.t_samples / (kSpp * f);
    CHECK(fabs(t_arr - tau_us * 1e-6) < 0.5 / f);  // a rectangular burst: half-peak within half a period
    int start = 0, len = plateau_gate(a.t_samples, 16, 4096, &start);
    CHECK(len == 7 * kSpp);
    IQ v = lockin(d, start, len);
    CHECK(fabs(hypot(v.i, v.q) - 500.0) < 1e-3);
    double lag_deg = fmod(atan2(v.q, v.i) * 180 / kPi + 360.0, 360.0);
    double want = fmod(360.0 * f * tau_us * 1e-6, 360.0);  // the protocol: round(360000 f t) mod 360000 mdeg
    double diff = fabs(lag_deg - want);
    CHECK(fmin(diff, 360.0 - diff) < 1e-3);
  }
  // an input below the noise is not taken for an arrival
  for (int k = 0; k < 4096; ++k) d[k] = 0.0f;
  envelope(d, 4096, env);
  CHECK(!find_arrival(env, 4096, 3.0).found);
}

static void test_frontend_and_steps() {
  Cplx h = butterworth4(150000.0, 150000.0);
  CHECK(fabs(hypot(h.re, h.im) - 1.0 / sqrt(2.0)) < 1e-9);  // -3 dB at the cut-off
  CHECK(fabs(aa_lag_rad(150000.0, 150000.0) - kPi) < 1e-9);  // 4 poles: 180 deg at the cut-off
  Cplx h50 = butterworth4(50000.0, 150000.0);
  CHECK(fabs(-atan2(h50.im, h50.re) - aa_lag_rad(50000.0, 150000.0)) < 1e-9);
  double gd = aa_group_delay_s(1000.0, 150000.0);  // low-frequency group delay: sum(a_i) / (2 pi fc)
  CHECK(fabs(gd - (2 * sin(kPi / 8) + 2 * cos(kPi / 8)) / (2 * kPi * 150000.0)) < 1e-9);
  RigConfig c = default_config();
  const AxisConfig& t = c.axis[0];
  CHECK(units_to_steps(t, 1000) == 800 && units_to_steps(t, -90000) == -72000 && units_to_steps(t, 1) == 1);
  CHECK(units_to_steps(t, -1) == -1 && units_to_steps(t, 2) == 2);
  CHECK(fabs(speed_of_sound_m_s(0.0) - 331.3) < 1e-12);
}

int main() {
  test_crc_and_framing();
  test_line_reader();
  test_lockin_sign_and_amplitude();
  test_frontend_and_steps();
  printf("%d checks, %d failed\n", g_checks, g_failed);
  return g_failed ? 1 : 0;
}
