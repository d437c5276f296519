// rig-sim: the rig firmware (board-independent core) on a Linux host, with simulated hardware,
// speaking protocol v1 on a pseudo-terminal. It prints the stable path to open (the link) on
// stdout once it is ready, and runs until SIGTERM or Ctrl-C.
//
//   rig-sim --truth truth.txt --link /tmp/rig [--speed 50] [--seed 1] [--reset-at SEQ ...]
//
// Capture from it with `difflattice capture lobe OUT.csv --port /tmp/rig ...`.
#include <errno.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <memory>
#include <string>

#include "sim_hal.h"

namespace {

volatile sig_atomic_t g_stop = 0;
void on_signal(int) { g_stop = 1; }

const char kUsage[] =
    "usage: rig-sim --truth FILE --link PATH [options]\n"
    "  --truth FILE            ground-truth table (firmware/tools/truth_table.py writes it)\n"
    "  --link PATH             stable path to publish (a symlink to the pseudo-terminal)\n"
    "  --speed X               simulated time runs X times faster than real time (default 50)\n"
    "  --seed N                noise seed (default 1)\n"
    "  --temperature-c T       air temperature [degC] (default 21)\n"
    "  --noise-uV S            white noise per ADC sample at the microphone [uV] (default 60)\n"
    "  --amp-jitter R          relative amplitude jitter per burst (default 0.005)\n"
    "  --phase-jitter-deg D    phase jitter per burst [deg] (default 0.3)\n"
    "  --tau-periods P         envelope time constant [carrier periods] (default 1)\n"
    "  --lobe-range-m R        lobe rig range, for the firmware's gate prediction (default 1)\n"
    "  --reset-at SEQ          watchdog reset while sending point SEQ (repeatable; each once)\n"
    "  --rig-id ID             rig id reported in IDN (default DL-SIM-0001)\n";

bool parse(int argc, char** argv, sim::Options* o) {
  for (int i = 1; i < argc; ++i) {
    std::string k = argv[i];
    if (k == "-h" || k == "--help") {
      fputs(kUsage, stdout);
      exit(0);
    }
    if (i + 1 >= argc) {
      fprintf(stderr, "rig-sim: %s needs a value\n%s", k.c_str(), kUsage);
      return false;
    }
    const char* v = argv[++i];
    char* end = nullptr;
    double x = strtod(v, &end);
    bool num = end && *end == 0;
    if (k == "--truth") o->truth_path = v;
    else if (k == "--link") o->link_path = v;
    else if (k == "--rig-id") o->rig_id = v;
    else if (!num) {
      fprintf(stderr, "rig-sim: %s %s: unknown option or not a number\n%s", k.c_str(), v, kUsage);
      return false;
    } else if (k == "--speed" && x > 0) o->speed = x;
    else if (k == "--seed") o->seed = static_cast<uint64_t>(x);
    else if (k == "--temperature-c") o->temperature_c = x;
    else if (k == "--noise-uV" && x >= 0) o->noise_uV = x;
    else if (k == "--amp-jitter" && x >= 0) o->amp_jitter = x;
    else if (k == "--phase-jitter-deg" && x >= 0) o->phase_jitter_deg = x;
    else if (k == "--tau-periods" && x > 0) o->tau_periods = x;
    else if (k == "--lobe-range-m" && x > 0) o->lobe_range_m = x;
    else if (k == "--reset-at" && x >= 0) o->reset_at.insert(static_cast<long>(x));
    else {
      fprintf(stderr, "rig-sim: %s %s: unknown option or value out of range\n%s", k.c_str(), v, kUsage);
      return false;
    }
  }
  if (o->truth_path.empty() || o->link_path.empty()) {
    fprintf(stderr, "rig-sim: --truth and --link are required\n%s", kUsage);
    return false;
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  sim::Options opt;
  if (!parse(argc, argv, &opt)) return 2;
  sim::Truth truth;
  std::string err;
  if (!truth.load(opt.truth_path, &err)) {
    fprintf(stderr, "rig-sim: %s\n", err.c_str());
    return 2;
  }
  rig::RigConfig cfg = rig::default_config();
  cfg.fw_version = "1.0.0-sim";
  cfg.rig_id = opt.rig_id.c_str();
  cfg.cal.lobe_range_m = opt.lobe_range_m;
  sim::SimHal hal(opt, truth, cfg);
  if (!hal.open_port(&err)) {
    fprintf(stderr, "rig-sim: %s\n", err.c_str());
    return 1;
  }
  signal(SIGTERM, on_signal);
  signal(SIGINT, on_signal);
  signal(SIGPIPE, SIG_IGN);
  printf("%s\n", opt.link_path.c_str());
  fflush(stdout);

  auto firmware = std::make_unique<rig::Rig>(hal, cfg);
  firmware->begin();
  while (!g_stop) {
    uint32_t wait_us = firmware->poll();
    hal.flush();
    if (hal.reset_pending()) {  // the watchdog bites: the firmware restarts, the mechanics stay put
      hal.rebooted();
      firmware = std::make_unique<rig::Rig>(hal, cfg);
      firmware->begin();
      continue;
    }
    double real_us = wait_us / opt.speed;
    if (real_us > 2000) real_us = 2000;  // serve input promptly
    if (!hal.host_present()) {
      timespec ts{0, static_cast<long>(real_us * 1000) + 1000000};
      nanosleep(&ts, nullptr);
      continue;
    }
    if (real_us < 1) continue;
    pollfd p{hal.fd(), POLLIN, 0};
    timespec ts{0, static_cast<long>(real_us * 1000)};
    ppoll(&p, 1, &ts, nullptr);
  }
  hal.close_port();
  return 0;
}
