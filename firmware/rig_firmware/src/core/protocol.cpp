#include "protocol.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

namespace rig {

uint16_t crc16(const uint8_t* data, size_t n) {
  uint16_t crc = 0xFFFF;  // CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no xor out
  for (size_t i = 0; i < n; ++i) {
    crc ^= static_cast<uint16_t>(data[i]) << 8;
    for (int b = 0; b < 8; ++b) crc = (crc & 0x8000) ? static_cast<uint16_t>((crc << 1) ^ 0x1021) : static_cast<uint16_t>(crc << 1);
  }
  return crc;
}

const char* err_name(ErrCode c) {
  switch (c) {
    case ErrCode::BadCrc: return "BADCRC";
    case ErrCode::Malformed: return "MALFORMED";
    case ErrCode::TooLong: return "TOOLONG";
    case ErrCode::BadCmd: return "BADCMD";
    case ErrCode::BadArg: return "BADARG";
    case ErrCode::Busy: return "BUSY";
    case ErrCode::NotHomed: return "NOTHOMED";
    case ErrCode::Limit: return "LIMIT";
    default: return "NONE";
  }
}

bool LineReader::feed(uint8_t b) {
  if (b == '$') {  // a new line starts: whatever came before it was a truncated line or junk
    len_ = 0;
    in_line_ = true;
    skipping_ = false;
    overflow_ = false;
  }
  if (skipping_) {
    if (b == '\n') skipping_ = false;
    return false;
  }
  if (!in_line_) return false;
  bool crlf = (b == '\n' && len_ == kMaxLine && buf_[len_ - 1] == '\r');
  if (len_ >= kMaxLine && !crlf) {  // longer than any line: report once, then drop to the next '$' or '\n'
    in_line_ = false;
    skipping_ = (b != '\n');
    overflow_ = true;
    len_ = 0;
    return true;
  }
  buf_[len_++] = static_cast<char>(b);
  if (b == '\n') {
    if (len_ >= 2 && buf_[len_ - 2] == '\r') {  // "\r\n" is tolerated: keep "\n" only
      buf_[len_ - 2] = '\n';
      --len_;
    }
    buf_[len_] = 0;
    in_line_ = false;
    overflow_ = false;
    return true;
  }
  return false;
}

namespace {

int hexval(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;  // upper case only
}

// Canonical decimal integer: -?(0|[1-9][0-9]*), no "-0", within int32.
bool parse_int(const char* s, size_t n, int32_t* out) {
  if (n == 0 || n > 11) return false;
  size_t i = 0;
  bool neg = false;
  if (s[0] == '-') {
    neg = true;
    i = 1;
    if (n == 1) return false;
  }
  if (s[i] == '0' && (n - i) > 1) return false;
  if (neg && s[i] == '0') return false;
  int64_t v = 0;
  for (; i < n; ++i) {
    if (s[i] < '0' || s[i] > '9') return false;
    v = v * 10 + (s[i] - '0');
  }
  if (neg) v = -v;
  if (v < INT32_MIN || v > INT32_MAX) return false;
  *out = static_cast<int32_t>(v);
  return true;
}

struct TypeSpec {
  const char* name;
  CmdType type;
  int n_fields;
};
const TypeSpec kTypes[] = {
    {"HELLO", CmdType::Hello, 1}, {"STAT", CmdType::Stat, 0},  {"HOME", CmdType::Home, 0},
    {"LOBE", CmdType::Lobe, 8},   {"WAVE", CmdType::Wave, 9},  {"ABORT", CmdType::Abort, 1},
};

}  // namespace

ParseResult parse_line(const char* line, size_t n) {
  ParseResult r{};
  r.err = ErrCode::Malformed;
  strcpy(r.detail, "-");
  if (n > kMaxLine) {
    r.err = ErrCode::TooLong;
    return r;
  }
  if (n < 7 || line[0] != '$' || line[n - 1] != '\n' || line[n - 6] != '*') return r;
  const char* body = line + 1;
  size_t blen = n - 7;
  for (size_t i = 0; i < blen; ++i) {
    char c = body[i];
    if (c == '$' || c == '*' || c < 0x20 || c > 0x7e) return r;
  }
  uint16_t want = 0;
  for (int i = 0; i < 4; ++i) {
    int h = hexval(line[n - 5 + i]);
    if (h < 0) return r;
    want = static_cast<uint16_t>((want << 4) | h);
  }
  if (crc16(reinterpret_cast<const uint8_t*>(body), blen) != want) {
    r.err = ErrCode::BadCrc;
    return r;
  }
  // split into TYPE and fields
  const char* starts[kMaxFields + 1];
  size_t lens[kMaxFields + 1];
  int nf = 0;
  size_t s = 0;
  for (size_t i = 0; i <= blen; ++i) {
    if (i == blen || body[i] == ',') {
      if (nf > kMaxFields) {
        r.err = ErrCode::BadArg;
        return r;
      }
      starts[nf] = body + s;
      lens[nf] = i - s;
      ++nf;
      s = i + 1;
    }
  }
  size_t tl = lens[0];
  bool upper = tl > 0;
  for (size_t i = 0; i < tl; ++i) upper = upper && starts[0][i] >= 'A' && starts[0][i] <= 'Z';
  if (!upper) {
    r.err = ErrCode::BadCmd;
    return r;
  }
  if (tl <= 8) {
    memcpy(r.detail, starts[0], tl);
    r.detail[tl] = 0;
  }
  const TypeSpec* spec = nullptr;
  for (const TypeSpec& t : kTypes)
    if (strlen(t.name) == tl && memcmp(t.name, starts[0], tl) == 0) spec = &t;
  if (!spec) {
    r.err = ErrCode::BadCmd;
    return r;
  }
  if (nf - 1 != spec->n_fields) {
    r.err = ErrCode::BadArg;
    return r;
  }
  int32_t v[kMaxFields] = {};
  for (int i = 1; i < nf; ++i) {
    if (!parse_int(starts[i], lens[i], &v[i - 1])) {
      r.err = ErrCode::BadArg;
      return r;
    }
  }
  Command& c = r.cmd;
  c.type = spec->type;
  switch (spec->type) {
    case CmdType::Hello: c.proto = v[0]; break;
    case CmdType::Abort: c.scan = v[0]; break;
    case CmdType::Lobe:
      c.scan = v[0]; c.first_seq = v[1]; c.n = v[2]; c.start = v[3]; c.step = v[4];
      c.n_avg = v[5]; c.cycles = v[6]; c.freq_hz = v[7];
      break;
    case CmdType::Wave:
      c.scan = v[0]; c.first_seq = v[1]; c.n = v[2]; c.start = v[3]; c.step = v[4]; c.z_um = v[5];
      c.n_avg = v[6]; c.cycles = v[7]; c.freq_hz = v[8];
      break;
    default: break;
  }
  r.err = ErrCode::None;
  return r;
}

size_t format_line(char* out, const char* fmt, ...) {
  char body[kMaxLine + 1];
  va_list ap;
  va_start(ap, fmt);
  int n = vsnprintf(body, sizeof body, fmt, ap);
  va_end(ap);
  if (n < 0 || static_cast<size_t>(n) + 7 > kMaxLine) return 0;
  uint16_t crc = crc16(reinterpret_cast<const uint8_t*>(body), static_cast<size_t>(n));
  int m = snprintf(out, kMaxLine + 1, "$%s*%04X\n", body, crc);
  return m > 0 ? static_cast<size_t>(m) : 0;
}

}  // namespace rig
