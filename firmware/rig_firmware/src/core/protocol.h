// Rig serial protocol v1 (docs: /shared/rig-protocol.md, docs/capture.md): framing, CRC-16,
// a resynchronising line reader, strict parsing of host commands and formatting of rig lines.
//
// A line is "$BODY*CRC\n", at most 120 bytes from '$' through '\n'; a '\r' before the '\n' is
// tolerated. CRC-16/CCITT-FALSE over BODY, four upper-case hex digits. Numbers are canonical
// decimal integers. Board-independent; no heap.
#pragma once

#include <stddef.h>
#include <stdint.h>

namespace rig {

constexpr int kProtocolVersion = 1;
constexpr size_t kMaxLine = 120;  // '$' .. '\n' inclusive
constexpr int kMaxFields = 12;

uint16_t crc16(const uint8_t* data, size_t n);

enum class ErrCode : uint8_t { None, BadCrc, Malformed, TooLong, BadCmd, BadArg, Busy, NotHomed, Limit };
const char* err_name(ErrCode c);

enum class CmdType : uint8_t { Hello, Stat, Home, Lobe, Wave, Abort };

// A host command, fields in the order of the line. Unused fields are 0.
struct Command {
  CmdType type;
  int32_t proto;                                   // HELLO
  int32_t scan, first_seq, n;                      // LOBE, WAVE (scan also ABORT)
  int32_t start, step;                             // LOBE: mdeg; WAVE: x0_um, dx_um
  int32_t z_um;                                    // WAVE
  int32_t n_avg, cycles, freq_hz;                  // LOBE, WAVE
};

// Result of reading one line: a command, or an error to answer with ERR,<code>,<detail>.
struct ParseResult {
  ErrCode err;            // None: `cmd` is valid
  Command cmd;
  char detail[9];         // the command's TYPE when known (<= 8 letters), else "-"
};

// Check the framing of one line ('$' .. '\n') and parse it as a host command.
ParseResult parse_line(const char* line, size_t n);

// Splits a byte stream into lines, resynchronising on the last '$' before each '\n'. Bytes
// outside a line are dropped; an over-long line is reported once as TOOLONG.
class LineReader {
 public:
  // Feed one byte; returns true when `line()` holds a complete candidate line (from '$' through
  // '\n') or `overflow()` is set (a line exceeded the limit: answer ERR,TOOLONG).
  bool feed(uint8_t b);
  const char* line() const { return buf_; }
  size_t size() const { return len_; }
  bool overflow() const { return overflow_; }
  void reset() { len_ = 0; in_line_ = false; overflow_ = false; }

 private:
  char buf_[kMaxLine + 2];
  size_t len_ = 0;
  bool in_line_ = false;
  bool overflow_ = false;
  bool skipping_ = false;  // inside an over-long line: drop bytes until '$' or '\n'
};

// Formats "$BODY*CRC\n" into out (>= kMaxLine + 1 bytes) from a printf-style BODY; returns the
// line's length, or 0 if it would exceed kMaxLine (a bug: every line of v1 fits).
size_t format_line(char* out, const char* fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

}  // namespace rig
