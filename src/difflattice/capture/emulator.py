"""Rig emulator: a process that behaves like the rig firmware on a pseudo-terminal.

The emulator opens a pseudo-terminal, puts it in raw mode, publishes a stable symlink to it and
speaks protocol v1 on it (:mod:`difflattice.capture.protocol`) exactly as the firmware does:
``BOOT`` after every (re)boot, heartbeats, ``HOME``, ``LOBE``/``WAVE`` scans computed from a
ground-truth transducer (:mod:`difflattice.capture.groundtruth`) with measurement noise and a
drifting temperature, and ``ABORT``. Faults can be injected (:class:`Faults`): garbage, bad CRC,
truncated lines, pauses (heartbeats go on), freezes (total silence), a reset mid-scan,
unplug/replug (the pseudo-terminal and the link vanish, then come back under the same link),
another protocol version, and silence.

Noise is a deterministic function of ``(seed, scan parameters, seq)``: a point sent again after a
fault repeats its values, so tests can check every value exactly (:meth:`RigModel.measure`).

Run it with ``python -m difflattice.capture.emulator --link /tmp/rig ...`` or
``difflattice rig emulate ...`` (it prints the path to use and runs until interrupted), or from
Python with :func:`start_emulator`, which starts it in its own process.
"""

from __future__ import annotations

import argparse
import dataclasses
import errno
import json
import math
import os
import random
import select
import signal
import subprocess
import sys
import time
import tty
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np

from ..config import Parser, Section, add_options, setting, specs
from . import protocol as P
from .groundtruth import Piston, TableTransducer, lobe_truth, make_transducer, wave_truth

TURNTABLE_LIMIT_MDEG = 180_000
STAGE_X_LIMIT_UM = 100_000
STAGE_Z_LIMIT_UM = (1, 500_000)


@dataclass(frozen=True)
class RigConfig(Section):
    """The emulated rig: identity, geometry, environment and pace.

    The air temperature drifts by ``drift_c_per_h`` plus a 10-minute oscillation of amplitude
    ``wobble_c`` (:meth:`temperature_at`). Each key is declared once here; the emulator's
    command-line options and the docs table come from these declarations.
    """

    SECTION: ClassVar[str] = "rig"
    rig_id: str = setting("EMU-0001", kind="str", doc="rig id reported in IDN")
    fw_version: str = setting("0.3.1-emu", kind="str", doc="firmware version reported in IDN and BOOT")
    range_m: float = setting(1.0, kind="number", gt=0, le=100, unit="m", doc="microphone range of the lobe rig")
    temperature_c: float = setting(21.0, kind="number", ge=-40, le=60, unit="degC", doc="air temperature at start")
    drift_c_per_h: float = setting(0.5, kind="number", unit="degC/h", doc="temperature drift")
    wobble_c: float = setting(
        0.05, kind="number", ge=0, unit="degC", doc="amplitude of a 10-minute temperature oscillation"
    )
    heartbeat_s: float = setting(1.0, kind="number", gt=0, unit="s", doc="silence before a heartbeat (firmware: 1 s)")
    point_s: float = setting(0.005, kind="number", ge=0, unit="s", doc="measurement time per point")
    home_s: float = setting(0.5, kind="number", ge=0, unit="s", doc="homing time")
    baud: int = setting(
        115_200, kind="int", ge=0, unit="bit/s", doc="line rate the output is paced at, 10 bits per byte (0: unpaced)"
    )

    def temperature_at(self, t_s: float) -> float:
        """Air temperature [degC] ``t_s`` seconds after the emulator started."""
        return self.temperature_c + self.drift_c_per_h * t_s / 3600 + self.wobble_c * math.sin(2 * math.pi * t_s / 600)


@dataclass(frozen=True)
class Noise(Section):
    """Measurement noise: standard deviations of a single burst; reports average ``n_avg``.

    Each burst's envelope peak is ``|A + e|`` with ``e ~ N(0, (amp_rel A)^2 + amp_uV^2)``; the rig
    reports their mean and sample sd. Arrival time and phase get Gaussian noise of ``tof_ns`` and
    ``phase_mdeg`` divided by ``sqrt(n_avg)``.
    """

    SECTION: ClassVar[str] = "noise"
    amp_rel: float = setting(0.005, kind="number", ge=0, unit="1", doc="relative amplitude noise per burst")
    amp_uV: float = setting(20.0, kind="number", ge=0, unit="uV", doc="absolute amplitude noise per burst")
    tof_ns: float = setting(50.0, kind="number", ge=0, unit="ns", doc="arrival-time noise per burst")
    phase_mdeg: float = setting(300.0, kind="number", ge=0, unit="mdeg", doc="phase noise per burst")


@dataclass(frozen=True)
class Faults(Section):
    """Injectable faults.

    Per line sent, with the given probability: ``garbage``, ``bad_crc``, ``truncate`` (half of the
    time the next line is glued on). At given points ``seq`` (each once, the first time the rig is
    about to send that seq): ``pause_at``, ``freeze_at`` (input not read either), ``reset_at``
    (half the line, then a watchdog reset: ``BOOT``, idle, not homed), ``unplug_at`` (the
    pseudo-terminal and the link disappear; the rig, USB-powered, reboots).
    """

    SECTION: ClassVar[str] = "faults"
    garbage: float = setting(
        0.0, kind="number", ge=0, le=1, doc="probability per line of 1-16 random bytes inserted before or inside it"
    )
    bad_crc: float = setting(0.0, kind="number", ge=0, le=1, doc="probability per line of one corrupted byte")
    truncate: float = setting(0.0, kind="number", ge=0, le=1, doc="probability per line of a truncated line")
    pause_at: tuple[int, ...] = setting(
        (), kind="list", items="int", ge=0, doc="seqs before which the rig pauses (heartbeats go on)"
    )
    pause_s: float = setting(4.0, kind="number", ge=0, unit="s", doc="pause length")
    freeze_at: tuple[int, ...] = setting(
        (), kind="list", items="int", ge=0, doc="seqs before which the firmware hangs (total silence)"
    )
    freeze_s: float = setting(4.0, kind="number", ge=0, unit="s", doc="freeze length")
    reset_at: tuple[int, ...] = setting(
        (), kind="list", items="int", ge=0, doc="seqs at which the rig resets (half a line, then BOOT)"
    )
    unplug_at: tuple[int, ...] = setting(
        (), kind="list", items="int", ge=0, doc="seqs at which the cable is pulled (link gone, then back, rig rebooted)"
    )
    unplug_s: float = setting(1.0, kind="number", ge=0, unit="s", doc="time unplugged")
    version: int = setting(P.PROTOCOL_VERSION, kind="int", ge=0, doc="protocol version answered to HELLO")
    silent: bool = setting(False, kind="bool", doc="never send anything")


@dataclass(frozen=True)
class EmulatorConfig:
    """Everything an emulator process needs, JSON-able (see :func:`start_emulator`)."""

    link_path: str
    transducer: dict[str, Any]
    rig: RigConfig = field(default_factory=RigConfig)
    noise: Noise = field(default_factory=Noise)
    faults: Faults = field(default_factory=Faults)
    seed: int = 0

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self))

    @classmethod
    def from_json(cls, text: str) -> EmulatorConfig:
        doc = json.loads(text)
        return cls(
            link_path=doc["link_path"],
            transducer=doc["transducer"],
            rig=_build(RigConfig, doc["rig"], "rig"),
            noise=_build(Noise, doc["noise"], "noise"),
            faults=_build(Faults, doc["faults"], "fault"),
            seed=doc["seed"],
        )


_S = TypeVar("_S", bound=Section)


def _build(cls: type[_S], values: dict[str, Any] | None, what: str) -> _S:
    """``cls(**values)``, refusing keys ``cls`` does not declare (lists become tuples in ``Section``)."""
    names = {s.name for s in specs(cls)}
    unknown = set(values or {}) - names
    if unknown:
        raise ValueError(f"unknown {what} key(s) {sorted(unknown)}; known: {sorted(names)}")
    return cls(**(values or {}))


def make_config(
    *,
    link_path: str | Path,
    transducer: dict[str, Any],
    faults: dict[str, Any] | None = None,
    seed: int = 0,
    noise: bool | dict[str, float] = True,
    rig: dict[str, Any] | None = None,
) -> EmulatorConfig:
    """Check and assemble an :class:`EmulatorConfig` (arguments as :func:`start_emulator`)."""
    if noise is True:
        noise_cfg = Noise()
    elif noise is False:
        noise_cfg = Noise(0.0, 0.0, 0.0, 0.0)
    else:
        noise_cfg = _build(Noise, noise, "noise")
    cfg = EmulatorConfig(
        link_path=str(Path(link_path).absolute()),
        transducer=dict(transducer),
        rig=_build(RigConfig, rig, "rig"),
        noise=noise_cfg,
        faults=_build(Faults, faults, "fault"),
        seed=int(seed),
    )
    make_transducer(cfg.transducer)  # fail here, in the caller's process, on a bad spec
    return cfg


# --------------------------------------------------------------------------------------------
# Measurements
# --------------------------------------------------------------------------------------------


class RigModel:
    """The measurements the emulated rig reports, from its ground truth, noise and seed."""

    def __init__(self, cfg: EmulatorConfig) -> None:
        self.transducer: Piston | TableTransducer = make_transducer(cfg.transducer)
        self.rig = cfg.rig
        self.noise = cfg.noise
        self.seed = cfg.seed

    def check(self, cmd: P.Lobe | P.Wave) -> None:
        """Raise ``ValueError`` if the ground truth cannot produce the points of ``cmd``."""
        for seq in (cmd.first_seq, cmd.n - 1):
            self.measure(cmd, seq, self.rig.temperature_c)

    def _rng(self, cmd: P.Lobe | P.Wave, seq: int) -> np.random.Generator:
        pos = cmd.start_mdeg + seq * cmd.step_mdeg if isinstance(cmd, P.Lobe) else cmd.x0_um + seq * cmd.dx_um
        z = cmd.z_um if isinstance(cmd, P.Wave) else 0
        words = [self.seed, isinstance(cmd, P.Wave), pos + 2**31, z, cmd.n_avg, cmd.cycles, cmd.freq_hz]
        return np.random.default_rng(np.random.SeedSequence(words))

    def _bursts(self, rng: np.random.Generator, amp: float, n_avg: int) -> tuple[int, int]:
        sd = math.hypot(self.noise.amp_rel * amp, self.noise.amp_uV)
        peaks = np.abs(amp + sd * rng.standard_normal(n_avg))
        return round(float(peaks.mean())), round(float(peaks.std(ddof=1))) if n_avg > 1 else 0

    def measure(self, cmd: P.Lobe | P.Wave, seq: int, temperature_c: float) -> P.Lob | P.Wav:
        """The line the rig sends for point ``seq`` of ``cmd`` at air temperature ``temperature_c``."""
        rng = self._rng(cmd, seq)
        temp_cC = round(temperature_c * 100)
        jitter = 1 / math.sqrt(cmd.n_avg)
        if isinstance(cmd, P.Lobe):
            angle_mdeg = cmd.start_mdeg + seq * cmd.step_mdeg
            amp, tof_s = lobe_truth(
                self.transducer,
                angle_mdeg / 1000,
                range_m=self.rig.range_m,
                freq_hz=cmd.freq_hz,
                temperature_c=temperature_c,
            )
            amp_uV, amp_sd_uV = self._bursts(rng, float(amp[0]), cmd.n_avg)
            tof_ns = round(tof_s * 1e9 + self.noise.tof_ns * jitter * rng.standard_normal())
            return P.Lob(cmd.scan, seq, angle_mdeg, amp_uV, amp_sd_uV, tof_ns, temp_cC)
        x_um = cmd.x0_um + seq * cmd.dx_um
        tof, phase, amp = wave_truth(
            self.transducer, x_um * 1e-6, z_m=cmd.z_um * 1e-6, freq_hz=cmd.freq_hz, temperature_c=temperature_c
        )
        amp_uV, _ = self._bursts(rng, float(amp[0]), cmd.n_avg)
        tof_ns = round(float(tof[0]) * 1e9 + self.noise.tof_ns * jitter * rng.standard_normal())
        # the lag behind the drive, reduced to [0, 360000) mdeg (rig protocol, "Field conventions")
        phase_mdeg = round(float(phase[0]) * 1000 + self.noise.phase_mdeg * jitter * rng.standard_normal())
        phase_mdeg %= 360_000
        return P.Wav(cmd.scan, seq, x_um, cmd.z_um, tof_ns, phase_mdeg, amp_uV, temp_cC)


# --------------------------------------------------------------------------------------------
# The firmware on a pseudo-terminal
# --------------------------------------------------------------------------------------------


@dataclass
class _Scan:
    cmd: P.Lobe | P.Wave
    next_seq: int
    due: float
    sent: int = 0


class Emulator:
    """The emulated rig: firmware state machine, fault injection and the pseudo-terminal."""

    def __init__(self, cfg: EmulatorConfig) -> None:
        self.cfg = cfg
        self.model = RigModel(cfg)
        self.faults = cfg.faults
        self.rng = random.Random(cfg.seed)
        self.link = Path(cfg.link_path)
        self.t0 = time.monotonic()
        self.master = -1
        self.pts_name = ""
        self.host_present = False
        self.out: deque[bytes] = deque()
        self.txbuf = b""
        self.tx_ready = 0.0
        self.rx = P.LineBuffer()
        self.pending = {
            name: set(getattr(cfg.faults, name)) for name in ("pause_at", "freeze_at", "reset_at", "unplug_at")
        }
        self.boot_id = 0
        self._boot("POR", self.t0)

    # firmware state -------------------------------------------------------------------------

    def _boot(self, reason: P.BootReason, now: float) -> None:
        old = self.boot_id
        while self.boot_id == old:  # a new boot id at every boot
            self.boot_id = self.rng.randrange(1, 65536)
        self.t_boot = now
        self.homed = False
        self.homing_until: float | None = None
        self.scan: _Scan | None = None
        self.last_scan = (0, 0)
        self.rx = P.LineBuffer()
        self.last_line = now
        self._send(P.Boot(self.cfg.rig.fw_version, self.boot_id, reason), now)

    def _state(self) -> P.State:
        return "SCAN" if self.scan else "IDLE"

    def _hbt(self, now: float) -> P.Hbt:
        scan, next_seq = (self.scan.cmd.scan, self.scan.next_seq) if self.scan else self.last_scan
        return P.Hbt(int((now - self.t_boot) * 1000), self._state(), scan, next_seq)

    def _send(self, msg: P.Message, now: float) -> None:
        self.last_line = now
        if self.faults.silent:
            return
        self.out.append(self._corrupt(P.encode(msg)))

    def _corrupt(self, line: bytes) -> bytes:
        f, rng = self.faults, self.rng
        if rng.random() < f.bad_crc:
            i = rng.randrange(1, len(line) - 1)
            line = line[:i] + bytes([rng.choice([c for c in range(33, 127) if c != line[i]])]) + line[i + 1 :]
        if rng.random() < f.truncate:
            line = line[: rng.randrange(1, len(line) - 1)] + (b"\n" if rng.random() < 0.5 else b"")
        if rng.random() < f.garbage:
            i = rng.randrange(0, len(line))
            line = line[:i] + bytes(rng.randrange(256) for _ in range(rng.randrange(1, 17))) + line[i:]
        return line

    def _command(self, msg: P.Message, now: float) -> None:
        if isinstance(msg, P.Hello):
            f = self.cfg.rig
            self._send(P.Idn(self.faults.version, f.fw_version, f.rig_id, self.boot_id, self.homed, self._state()), now)
        elif isinstance(msg, P.Stat):
            self._send(self._hbt(now), now)
        elif isinstance(msg, P.Home):
            if self.scan:
                self._send(P.Err("BUSY", "HOME"), now)
            elif self.homing_until is None:
                self.homed = False
                self.homing_until = now + self.cfg.rig.home_s
        elif isinstance(msg, (P.Lobe, P.Wave)):
            self._start_scan(msg, now)
        elif isinstance(msg, P.Abort):
            if self.scan and self.scan.cmd.scan != msg.scan:
                self._send(P.Err("BADARG", "ABORT"), now)
            else:
                sent = self.scan.sent if self.scan else 0
                self._end_scan(now)
                self._send(P.End(msg.scan, sent, "ABORTED"), now)
        else:
            self._send(P.Err("BADCMD", msg.TYPE), now)

    def _start_scan(self, cmd: P.Lobe | P.Wave, now: float) -> None:
        if self.scan or self.homing_until is not None:
            return self._send(P.Err("BUSY", cmd.TYPE), now)
        ok = 0 <= cmd.first_seq < cmd.n <= 100_000 and 1 <= cmd.n_avg <= 1000 and 1 <= cmd.cycles <= 1000
        if not (ok and 1000 <= cmd.freq_hz <= 1_000_000):
            return self._send(P.Err("BADARG", cmd.TYPE), now)
        if isinstance(cmd, P.Lobe):
            ends = (cmd.start_mdeg, cmd.start_mdeg + (cmd.n - 1) * cmd.step_mdeg)
            inside = all(abs(a) <= TURNTABLE_LIMIT_MDEG for a in ends)
        else:
            ends = (cmd.x0_um, cmd.x0_um + (cmd.n - 1) * cmd.dx_um)
            zmin, zmax = STAGE_Z_LIMIT_UM
            inside = all(abs(x) <= STAGE_X_LIMIT_UM for x in ends) and zmin <= cmd.z_um <= zmax
        if not inside:
            return self._send(P.Err("LIMIT", cmd.TYPE), now)
        if not self.homed:
            return self._send(P.Err("NOTHOMED", cmd.TYPE), now)
        try:
            self.model.check(cmd)
        except ValueError:
            return self._send(P.Err("BADARG", cmd.TYPE), now)
        self._send(P.Ack(cmd.TYPE, cmd.scan), now)
        self.scan = _Scan(cmd, cmd.first_seq, now + self.cfg.rig.point_s)

    def _end_scan(self, now: float) -> None:
        if self.scan:
            self.last_scan = (self.scan.cmd.scan, self.scan.next_seq)
        self.scan = None

    def _tick(self, now: float) -> None:
        """Advance the firmware to ``now``: homing, the next point of a scan, heartbeats."""
        if self.homing_until is not None and now >= self.homing_until:
            self.homing_until, self.homed = None, True
            self._send(P.Ack("HOME", 0), now)
        scan = self.scan
        if scan and now >= scan.due and not self.out and not self.txbuf:
            seq = scan.next_seq
            if self._fault_at("pause_at", seq):
                scan.due = now + self.faults.pause_s
                return
            if self._fault_at("freeze_at", seq):
                time.sleep(self.faults.freeze_s)  # hung firmware: nothing read, nothing sent
                scan.due = time.monotonic()
                return
            line = P.encode(self.model.measure(scan.cmd, seq, self.cfg.rig.temperature_at(now - self.t0)))
            if self._fault_at("reset_at", seq):
                if not self.faults.silent:
                    self.out.append(line[: len(line) // 2])
                self._boot("WDT", now)
                return
            if self._fault_at("unplug_at", seq):
                self._unplug()
                return
            self.last_line = now
            if not self.faults.silent:
                self.out.append(self._corrupt(line))
            scan.next_seq, scan.sent, scan.due = seq + 1, scan.sent + 1, now + self.cfg.rig.point_s
            if scan.next_seq >= scan.cmd.n:
                self._end_scan(now)
                self._send(P.End(scan.cmd.scan, scan.sent, "OK"), now)
        if now - self.last_line >= self.cfg.rig.heartbeat_s:
            self._send(self._hbt(now), now)

    def _fault_at(self, name: str, seq: int) -> bool:
        if seq in self.pending[name]:
            self.pending[name].discard(seq)
            return True
        return False

    # pseudo-terminal ------------------------------------------------------------------------

    def open_port(self) -> None:
        """Open a raw pseudo-terminal and point the link at it (atomically)."""
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo of what the rig sends before a host opens the port
        self.pts_name = os.ttyname(slave)
        os.close(slave)
        os.set_blocking(master, False)
        self.master, self.host_present = master, False
        self.out.clear()
        self.txbuf = b""
        self.link.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.tmp")
        tmp.unlink(missing_ok=True)
        os.symlink(self.pts_name, tmp)
        os.replace(tmp, self.link)

    def close_port(self) -> None:
        """Close the pseudo-terminal and remove the link if it still points to it."""
        if self.master < 0:
            return
        os.close(self.master)
        self.master = -1
        try:
            if os.readlink(self.link) == self.pts_name:
                self.link.unlink()
        except OSError:
            pass

    def _unplug(self) -> None:
        self.close_port()
        time.sleep(self.faults.unplug_s)
        self.open_port()
        self._boot("POR", time.monotonic())

    def _read(self, now: float) -> None:
        try:
            data = os.read(self.master, 4096)
        except BlockingIOError:
            self.host_present = True
            return
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            self.host_present = False  # no host has the port open
            return
        self.host_present = True
        for item in self.rx.feed(data):
            if isinstance(item, P.BadLine):
                if item.reason != "JUNK":
                    self._send(P.Err(item.reason, "-"), now)
                continue
            try:
                msg = P.parse_body(item.body)
            except P.FrameError as exc:
                kind = item.body.split(b",")[0].decode("ascii", "replace")
                detail = kind if kind.isalpha() and kind.isupper() and len(kind) <= 8 else "-"
                self._send(P.Err(exc.code, detail), now)
                continue
            self._command(msg, now)

    def _write(self, now: float) -> None:
        while self.out or self.txbuf:
            if not self.host_present:
                self.out.clear()  # like USB with no host: what the rig sends is lost
                self.txbuf = b""
                return
            if not self.txbuf:
                if now < self.tx_ready:
                    return
                self.txbuf = self.out.popleft()
                if self.cfg.rig.baud:
                    self.tx_ready = now + 10 * len(self.txbuf) / self.cfg.rig.baud
            try:
                n = os.write(self.master, self.txbuf)
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno != errno.EIO:
                    raise
                self.host_present = False
                continue
            self.txbuf = self.txbuf[n:]

    def run(self) -> None:
        """Serve the rig until the process is told to stop."""
        while True:
            now = time.monotonic()
            self._read(now)
            self._tick(now)
            self._write(now)
            if not self.host_present:
                time.sleep(0.01)
                continue
            wake = [now + 1.0, self.last_line + self.cfg.rig.heartbeat_s]
            if self.scan:
                wake.append(self.scan.due)
            if self.homing_until is not None:
                wake.append(self.homing_until)
            if self.out or self.txbuf:
                wake.append(self.tx_ready)
            timeout = max(0.0, min(wake) - time.monotonic())
            wlist = [self.master] if self.txbuf or (self.out and now >= self.tx_ready) else []
            select.select([self.master], wlist, [], timeout)


# --------------------------------------------------------------------------------------------
# Process entry points
# --------------------------------------------------------------------------------------------

DEFAULT_LINK = "/tmp/difflattice-rig"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the emulator's options to ``parser`` (shared by ``difflattice rig emulate``)."""
    parser.add_argument("--link", default=DEFAULT_LINK, help="stable path to publish")
    truth = parser.add_mutually_exclusive_group()
    truth.add_argument("--piston-diameter-mm", type=float, default=38.4, help="ground truth: circular piston [mm]")
    truth.add_argument(
        "--table",
        type=Path,
        help="ground truth: transducer table JSON (see groundtruth.TableTransducer; default: the piston)",
    )
    parser.add_argument(
        "--sensitivity-uV",
        type=float,
        help="on-axis amplitude at 1 m [uV] (piston) or table scale (default: 50000 for the piston, 1 for a table)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of noise and faults")
    parser.add_argument("--no-noise", action="store_true", help="report noise-free values")
    add_options(parser.add_argument_group("rig"), RigConfig, dest_prefix="rig.", suppress_defaults=True)
    add_options(parser.add_argument_group("faults"), Faults, dest_prefix="faults.", suppress_defaults=True)
    parser.add_argument("--config", help=argparse.SUPPRESS)  # whole config as JSON (start_emulator)


def config_from_args(args: argparse.Namespace) -> EmulatorConfig:
    """The :class:`EmulatorConfig` that parsed options describe."""
    if args.config:
        return EmulatorConfig.from_json(args.config)
    if args.table:
        transducer: dict[str, Any] = {"kind": "table", "path": str(args.table.absolute())}
    else:
        transducer = {"kind": "piston", "diameter_m": args.piston_diameter_mm / 1000}
    if args.sensitivity_uV is not None:
        transducer["sensitivity_uV"] = args.sensitivity_uV
    groups: dict[str, dict[str, Any]] = {"rig": {}, "faults": {}}
    for dest, value in vars(args).items():
        group, _, name = dest.partition(".")
        if group in groups and name:
            groups[group][name] = value
    return make_config(link_path=args.link, transducer=transducer, seed=args.seed, noise=not args.no_noise, **groups)


def serve(cfg: EmulatorConfig, *, announce: bool = True) -> None:
    """Run the emulator in this process until SIGTERM or Ctrl-C; print the link path when ready."""
    import scipy.special  # noqa: F401 - loaded now, so that the first scan does not wait for it

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    signal.signal(signal.SIGINT, signal.default_int_handler)  # Ctrl-C stops it, even if started in background
    emulator = Emulator(cfg)
    emulator.open_port()
    try:
        if announce:
            print(cfg.link_path, flush=True)
        emulator.run()
    except KeyboardInterrupt:
        pass
    finally:
        emulator.close_port()


class EmulatorHandle:
    """A running emulator process: ``path`` is the stable link to open; ``stop()`` ends it."""

    def __init__(self, process: subprocess.Popen[str], path: Path, config: EmulatorConfig) -> None:
        self.process = process
        self.path = path
        self.config = config

    def stop(self, timeout_s: float = 5.0) -> None:
        """Terminate the emulator (SIGTERM, then SIGKILL after ``timeout_s``) and remove its link."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.process.stdout:
            self.process.stdout.close()
        if self.path.is_symlink() and not self.path.exists():
            self.path.unlink()

    def __enter__(self) -> EmulatorHandle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def start_emulator(
    *,
    link_path: str | Path,
    transducer: dict[str, Any],
    faults: dict[str, Any] | None = None,
    seed: int = 0,
    noise: bool | dict[str, float] = True,
    rig: dict[str, Any] | None = None,
    startup_timeout_s: float = 20.0,
) -> EmulatorHandle:
    """Start a rig emulator in its own process and return once its link is published.

    ``transducer``: ``{"kind": "piston", "diameter_m": 0.0384, "sensitivity_uV": 50000}`` or
    ``{"kind": "table", "path": "truth.json", "sensitivity_uV": 1.0}``
    (:func:`~difflattice.capture.groundtruth.make_transducer`). ``faults``: keys of
    :class:`Faults`. ``noise``: True (default levels), False (none) or keys of :class:`Noise`.
    ``rig``: keys of :class:`RigConfig` (identity, range, temperature, drift, pace).
    """
    cfg = make_config(link_path=link_path, transducer=transducer, faults=faults, seed=seed, noise=noise, rig=rig)
    cmd = [sys.executable, "-m", "difflattice.capture.emulator", "--config", cfg.to_json()]
    process = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], startup_timeout_s)
    line = process.stdout.readline().strip() if ready else ""
    if not line:
        process.kill()
        process.wait()
        raise RuntimeError(
            f"the rig emulator did not start within {startup_timeout_s} s (exit code {process.returncode})"
        )
    return EmulatorHandle(process, Path(line), cfg)


def main(argv: list[str] | None = None) -> int:
    """``python -m difflattice.capture.emulator``: run an emulator, print its link path."""
    parser = Parser(prog="python -m difflattice.capture.emulator", description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    serve(config_from_args(parser.parse_args(argv)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
