"""Datasheet directivity records with provenance (data/datasheets/*.toml).

A record says where every number came from: the document (`source.document`, its revision or
date, where it was read (`source.url`), the figure or table, and the text quoted), the device
(`device`: part number, frequency, construction, outline dimensions where the document states
them) and what the document gives about the beam:

- `beam`: a stated beam angle (`total_angle_deg` or `half_angle_deg`) at `level_db` (e.g. -6),
  as printed in a specification table: one number, fitted by nothing (one number cannot tell a
  recess from a diameter), but it fixes the equivalent baffled piston (`equivalent_piston_diameter_m`);
- `table`: a digitised directivity (`angle_deg`, `level_db`) with the digitising method and an
  honest 1-sigma in dB (`sigma_db`, the plot's line width and grid read-off), from which
  `lobe()` builds the `fit.data.LobeData` that `fit.ladder` fits.

Records are checked on loading: a `ValueError` names the file, the key and the fix. Nothing is
invented: a record without a table says so (`lobe()` refuses, naming what is missing).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REQUIRED_SOURCE = ("document", "revision", "url", "location", "quote")
"""Keys of `[source]`: the document's name, its revision or issue date, where it was read, the
figure/table/row it was read from, and the quoted text (for a stated figure)."""


@dataclass(frozen=True)
class Datasheet:
    """A checked datasheet record (see the module docstring)."""

    path: Path
    part: str
    frequency_hz: float
    construction: str
    source: dict
    outline: dict
    half_angle_deg: float | None
    beam_level_db: float | None
    table: dict | None
    notes: str

    def lobe(self, *, range_m: float = 1.0, temperature_c: float = 20.0):
        """The digitised table as `fit.data.LobeData` (levels as printed, sigma from the record).
        ValueError if the record has no table."""
        from .data import LobeData

        if self.table is None:
            raise ValueError(
                f"{self.path}: {self.part} has no digitised directivity table (only "
                f"{'a stated beam angle' if self.half_angle_deg is not None else 'provenance'}); "
                "digitise the document's directivity figure into [table] (angle_deg, level_db, method, sigma_db)"
            )
        t = self.table
        ang = np.asarray(t["angle_deg"], float)
        order = np.argsort(ang, kind="stable")
        return LobeData(
            angle_deg=ang[order],
            level_db=np.asarray(t["level_db"], float)[order],
            sigma_db=np.full(len(ang), float(t["sigma_db"])),
            range_m=range_m,
            frequency_hz=self.frequency_hz,
            cycles=0.0,
            temperature_c=temperature_c,
            source=str(self.path),
        )

    def equivalent_piston_diameter_m(self, c_m_s: float = 343.2) -> float | None:
        """Diameter of the baffled rigid piston whose far field is `beam_level_db` down at the stated
        half-angle: 2 x (the root x of 20 log10 |2 J1(x)/x| = level) / (k sin t). A derived figure
        (not a fit): the piston in an infinite baffle, at the record's frequency."""
        if self.half_angle_deg is None or self.beam_level_db is None:
            return None
        from scipy.optimize import brentq
        from scipy.special import j1

        lvl = self.beam_level_db
        x = brentq(lambda v: 20 * math.log10(abs(2 * j1(v) / v)) - lvl, 1e-6, 3.8317)
        k = 2 * math.pi * self.frequency_hz / c_m_s
        return 2 * x / (k * math.sin(math.radians(self.half_angle_deg)))


def _need(path: Path, table: dict, key: str, what: str):
    if key not in table:
        raise ValueError(f"{path}: [{what}] needs {key!r}; fix: add it (see data/datasheets/README.md)")
    return table[key]


def load_datasheet(path: str | Path) -> Datasheet:
    """Read and check a datasheet record (TOML)."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise ValueError(f"{path}: cannot read the datasheet record ({e}); fix: check the path and the TOML") from None
    for sec in ("source", "device"):
        if not isinstance(raw.get(sec), dict):
            raise ValueError(f"{path}: section [{sec}] is required (see data/datasheets/README.md)")
    src, dev = raw["source"], raw["device"]
    for key in REQUIRED_SOURCE:
        v = _need(path, src, key, "source")
        if not isinstance(v, str) or not v.strip():
            raise ValueError(f"{path}: [source] {key} must be a non-empty string (say where the number came from)")
    part = str(_need(path, dev, "part", "device"))
    f = float(_need(path, dev, "frequency_hz", "device"))
    if not f > 0:
        raise ValueError(f"{path}: [device] frequency_hz = {f} must be > 0 Hz")
    outline = {k: float(v) for k, v in dev.items() if k.endswith("_m")}
    half = level = None
    beam = raw.get("beam")
    if beam is not None:
        level = float(_need(path, beam, "level_db", "beam"))
        if "half_angle_deg" in beam:
            half = float(beam["half_angle_deg"])
        elif "total_angle_deg" in beam:
            half = 0.5 * float(beam["total_angle_deg"])
        else:
            raise ValueError(f"{path}: [beam] needs total_angle_deg or half_angle_deg (as the document states it)")
        if not (0 < half < 90 and level < 0):
            raise ValueError(f"{path}: [beam] half angle {half} deg must be in (0, 90) and level_db {level} < 0")
    table = raw.get("table")
    if table is not None:
        for key in ("angle_deg", "level_db", "method", "sigma_db"):
            _need(path, table, key, "table")
        if len(table["angle_deg"]) != len(table["level_db"]) or len(table["angle_deg"]) < 3:
            raise ValueError(f"{path}: [table] angle_deg and level_db must have the same length, >= 3")
        if not float(table["sigma_db"]) > 0:
            raise ValueError(f"{path}: [table] sigma_db must be > 0 (the digitising 1-sigma, dB)")
    if beam is None and table is None:
        raise ValueError(f"{path}: nothing about the beam: give [beam] (a stated angle) or [table] (digitised)")
    return Datasheet(
        path=path,
        part=part,
        frequency_hz=f,
        construction=str(dev.get("construction", "")),
        source=dict(src),
        outline=outline,
        half_angle_deg=half,
        beam_level_db=level,
        table=None if table is None else dict(table),
        notes=str(raw.get("notes", "")),
    )
