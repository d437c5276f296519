"""A fit config's data, loaded in one pass: capture files (complete or not) or plain tables with
units in their headers, the masks, the checks of the data against the config (frequency, range,
temperature, z), the air the fit uses, and the warnings about unwise data."""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import ConfigWarning, message, show
from .config import FitConfig, ModelSection


def fit_air(cfg: FitConfig, data: FitData) -> dict[str, Any]:
    """The air a fit uses: {temperature_c, humidity_pct, pressure_pa, speed_of_sound_m_s, source},
    `source` naming, per key, where it came from ([air], [data], a capture file's header, default)."""
    from ..air import speed_of_sound_m_s
    from ..capture.files import is_capture_file, load_capture

    a = cfg.air
    if a.temperature_c is not None and cfg.data.temperature_c is not None:
        raise cfg.error("air.temperature_c", "is given twice ([data] temperature_c too): keep one")
    meta: dict[str, Any] = {}
    for path in data.paths:
        if is_capture_file(path):
            m = load_capture(path, allow_incomplete=True).metadata
            meta.update({k: m[k] for k in ("humidity_pct", "pressure_hpa") if m.get(k) is not None})
    src: dict[str, str] = {}
    t = a.temperature_c if a.temperature_c is not None else data.temperature_c
    src["temperature_c"] = "[air]" if a.temperature_c is not None else "capture or [data]"
    if a.humidity_pct is not None:
        h, src["humidity_pct"] = a.humidity_pct, "[air]"
    elif "humidity_pct" in meta:
        h, src["humidity_pct"] = float(meta["humidity_pct"]), "capture file"
    else:
        h, src["humidity_pct"] = 0.0, "default: dry (no [air] humidity_pct, none in the capture)"
    if a.pressure_pa is not None:
        p, src["pressure_pa"] = a.pressure_pa, "[air]"
    elif "pressure_hpa" in meta:
        p, src["pressure_pa"] = 100.0 * float(meta["pressure_hpa"]), "capture file"
    else:
        p, src["pressure_pa"] = 101325.0, "default (no [air] pressure_pa, none in the capture)"
    c = speed_of_sound_m_s(t, h, p)
    return {"temperature_c": t, "humidity_pct": h, "pressure_pa": p, "speed_of_sound_m_s": c, "source": src}


@dataclass(frozen=True)
class FitData:
    """The data a config names, loaded and checked: lobe and wave (or None), the files read, and
    notes on what was done with them (incomplete captures, masks, overrides) for the report."""

    lobe: Any
    wave: Any
    paths: tuple[Path, ...]
    notes: tuple[str, ...]
    frequency_hz: float
    temperature_c: float


def _resolve(cfg: FitConfig, key: str, value: str | None) -> Path:
    assert value is not None
    p = Path(value).expanduser()
    p = p if p.is_absolute() else cfg.base / p
    if not p.is_file():
        where = "not a file" if p.exists() else "not found"
        raise cfg.error(key, f"= {show(value)}: {where} ({p}); fix: paths are relative to the config file's folder")
    return p


def _capture(cfg: FitConfig, key: str, value: str | None, p: Path, notes: list[str]):
    from ..capture.errors import CaptureFileError
    from ..capture.files import describe_seqs, load_capture

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # incompleteness is reported below, once
            cap = load_capture(p, allow_incomplete=True)
    except CaptureFileError as e:
        raise cfg.error(key, f"= {show(value)} cannot be used: {e}") from None
    kind = key.split(".")[1]
    if cap.kind != kind:
        other = "wave" if kind == "lobe" else "lobe"
        raise cfg.error(
            key,
            f"= {show(value)} is a {cap.kind} capture (its header says kind: {cap.kind}); "
            f"fix: give it as {other} = {show(value)}",
        )
    n, total = len(cap.seq), cap.metadata["n_points"]
    if n == 0:
        raise cfg.error(
            key,
            f"= {show(value)} holds no points (0 of {total}); fix: capture the scan (re-run the "
            "capture command to continue it)",
        )
    if not cap.complete:
        notes.append(
            f"{p.name}: incomplete capture, fitted the {n} of {total} points present "
            f"(seq {describe_seqs(cap.missing)} missing); re-run the capture command to complete it"
        )
    return cap


def _check_agrees(
    cfg: FitConfig, key: str, given: float | None, actual: float, what: str, tol: float, unit: str
) -> None:
    if given is not None and abs(given - actual) > tol:
        raise cfg.error(
            key,
            f"= {show(given)} {unit} but {what} says {actual:g} {unit}; fix: correct it or leave it "
            "out (capture files carry their own)",
        )


def _lobe_data(cfg: FitConfig, notes: list[str]):
    from ..capture.errors import CaptureFileError
    from ..capture.files import is_capture_file, load_lobe_table
    from .data import lobe_from_capture, lobe_from_table

    d = cfg.data
    p = _resolve(cfg, "data.lobe", d.lobe)
    try:
        capture = is_capture_file(p)
    except CaptureFileError as e:
        raise cfg.error("data.lobe", f"= {show(d.lobe)} cannot be read: {e}") from None
    if capture:
        cap = _capture(cfg, "data.lobe", d.lobe, p, notes)
        _check_agrees(cfg, "data.frequency_hz", d.frequency_hz, cap.metadata["freq_hz"], p.name, 0.5, "Hz")
        _check_agrees(
            cfg, "data.range_m", d.range_m, cap.metadata["range_m"], p.name, 1e-6 + 1e-3 * cap.metadata["range_m"], "m"
        )
        if len(cap.seq) < 3:
            raise cfg.error("data.lobe", f"= {show(d.lobe)} holds only {len(cap.seq)} points; a fit needs >= 3")
        return lobe_from_capture(cap, min_sigma_db=d.lobe_sigma_db or 0.05), p, True
    try:
        table = load_lobe_table(p)
    except CaptureFileError as e:
        raise cfg.error(
            "data.lobe", f"= {show(d.lobe)} is neither a capture file nor a plain lobe table with a units header: {e}"
        ) from None
    for k, what in (
        ("frequency_hz", "the drive frequency in Hz"),
        ("range_m", "the measurement range in m"),
        ("temperature_c", "the air temperature in degC"),
        ("lobe_sigma_db", "the 1-sigma of the levels in dB"),
    ):
        if getattr(d, k) is None:
            raise cfg.error(f"data.{k}", f"is required: {p.name} is a plain table without metadata; fix: give {what}")
    assert d.frequency_hz is not None and d.range_m is not None  # checked just above
    assert d.temperature_c is not None and d.lobe_sigma_db is not None
    notes.append(
        f"{p.name}: plain lobe table ({len(table.angle_deg)} points), with frequency {d.frequency_hz:g} Hz, "
        f"range {d.range_m:g} m, {d.temperature_c:g} degC and sigma {d.lobe_sigma_db:g} dB from the config; columns {' and '.join(table.units)}"
    )
    return (
        lobe_from_table(
            table,
            frequency_hz=d.frequency_hz,
            range_m=d.range_m,
            temperature_c=d.temperature_c,
            sigma_db=d.lobe_sigma_db,
        ),
        p,
        False,
    )


def _wave_table(cfg: FitConfig, p: Path, notes: list[str]):
    """A plain wavefront table with a units header, with the metadata the config gives."""
    from ..capture.errors import CaptureFileError
    from ..capture.files import load_wave_table
    from .data import wave_from_table

    d = cfg.data
    try:
        table = load_wave_table(p)
    except CaptureFileError as e:
        raise cfg.error(
            "data.wave",
            f"= {show(d.wave)} is neither a capture file nor a plain wavefront table with a units header: {e}",
        ) from None
    for k, what in (
        ("frequency_hz", "the drive frequency in Hz"),
        ("temperature_c", "the air temperature in degC"),
        ("wave_z_m", "the scan line's distance from the face in m"),
    ):
        if getattr(d, k) is None:
            raise cfg.error(f"data.{k}", f"is required: {p.name} is a plain table without metadata; fix: give {what}")
    assert d.frequency_hz is not None and d.temperature_c is not None and d.wave_z_m is not None
    notes.append(
        f"{p.name}: plain wavefront table ({len(table.x_m)} points), with frequency {d.frequency_hz:g} Hz, "
        f"z {d.wave_z_m:g} m, {d.temperature_c:g} degC and sigma {cfg.solver.wave_sigma_deg:g} deg from the config; "
        f"columns {' and '.join(table.units)}"
    )
    wave = wave_from_table(
        table,
        frequency_hz=d.frequency_hz,
        z_m=d.wave_z_m,
        temperature_c=d.temperature_c,
        sigma_deg=cfg.solver.wave_sigma_deg,
    )
    return wave, p


def _wave_data(cfg: FitConfig, notes: list[str]):
    from ..capture.errors import CaptureFileError
    from ..capture.files import is_capture_file
    from .data import wave_from_capture

    d = cfg.data
    p = _resolve(cfg, "data.wave", d.wave)
    try:
        capture = is_capture_file(p)
    except CaptureFileError as e:
        raise cfg.error("data.wave", f"= {show(d.wave)} cannot be read: {e}") from None
    if not capture:
        return _wave_table(cfg, p, notes)
    cap = _capture(cfg, "data.wave", d.wave, p, notes)
    if d.wave_z_m is not None and len(cap.z_m):
        _check_agrees(cfg, "data.wave_z_m", d.wave_z_m, float(np.median(cap.z_m)), p.name, 1e-4, "m")
    _check_agrees(cfg, "data.frequency_hz", d.frequency_hz, cap.metadata["freq_hz"], p.name, 0.5, "Hz")
    if len(cap.seq) < 3:
        raise cfg.error("data.wave", f"= {show(d.wave)} holds only {len(cap.seq)} points; a fit needs >= 3")
    return wave_from_capture(cap, sigma_deg=cfg.solver.wave_sigma_deg), p


def checked_mask(cfg, key: str, ranges, positions, *, points: str, none: str) -> int:
    """How many of `positions` the inclusive `ranges` of config key `key` leave out: ConfigError if
    fewer than 3 points are left (the fix: narrow the ranges), a ConfigWarning if none is left out
    (`none` says of what, e.g. "point of lobe.csv (angles -90..90 deg)"). `points` names them in
    the error, e.g. "lobe points". Shared by the fit configs and the housed configs."""
    from .data import mask_counts

    n_out = mask_counts(positions, ranges)
    left = len(positions) - n_out
    if left < 3:
        raise cfg.error(
            key,
            f"= {show(ranges)} leaves {left} of {len(positions)} {points}; a fit needs >= 3; fix: narrow the ranges",
        )
    if n_out == 0:
        warnings.warn(message(cfg.path, key, None, f"= {show(ranges)} excludes no {none}"), ConfigWarning, stacklevel=3)
    return n_out


def masked_wave(cfg, wave, name: str) -> tuple[Any, str | None]:
    """`wave` less the positions `[data] wave_mask_m` leaves out (`checked_mask`), and the report's
    note on it (None without a mask); `name` is the wavefront file's name."""
    from .data import mask_wave

    ranges = cfg.data.wave_mask_m
    if not ranges:
        return wave, None
    n_out = checked_mask(
        cfg,
        "data.wave_mask_m",
        ranges,
        wave.x_m,
        points="wavefront points",
        none=f"point of {name} (x {wave.x_m.min():g}..{wave.x_m.max():g} m)",
    )
    return mask_wave(wave, ranges), f"{name}: wave_mask_m {show(ranges)} left out {n_out} points"


def load_fit_data(cfg: FitConfig) -> FitData:
    """Load and check the data `cfg` names. Raises `ConfigError` naming the key for a missing or
    unreadable file, a wave capture given as lobe (or the reverse), a plain table without the
    metadata it needs, disagreeing frequencies or ranges, no points, or a mask that leaves fewer
    than 3; issues `ConfigWarning` for a mask that excludes nothing, a floor below the data's
    dynamic range and a one-sided scan fitted with an asymmetric model."""
    from .data import mask_lobe

    d = cfg.data
    notes: list[str] = []
    paths: list[Path] = []
    lobe = wave = None
    if d.lobe is not None:
        lobe, p, is_capture = _lobe_data(cfg, notes)
        paths.append(p)
        if d.lobe_mask_deg:
            n_out = checked_mask(
                cfg,
                "data.lobe_mask_deg",
                d.lobe_mask_deg,
                lobe.angle_deg,
                points="lobe points",
                none=f"point of {p.name} (angles {lobe.angle_deg.min():g}..{lobe.angle_deg.max():g} deg)",
            )
            lobe = mask_lobe(lobe, d.lobe_mask_deg)
            notes.append(f"{p.name}: lobe_mask_deg {show(d.lobe_mask_deg)} left out {n_out} points")
        if d.temperature_c is not None and is_capture:
            notes.append(
                f"{p.name}: temperature {d.temperature_c:g} degC from the config replaces the "
                f"capture's {lobe.temperature_c:.2f} degC"
            )
            lobe = dataclasses.replace(lobe, temperature_c=d.temperature_c)
    if d.wave is not None:
        wave, p = _wave_data(cfg, notes)
        paths.append(p)
        wave, note = masked_wave(cfg, wave, p.name)
        if note:
            notes.append(note)
        if d.temperature_c is not None:
            notes.append(
                f"{p.name}: temperature {d.temperature_c:g} degC from the config replaces the "
                f"capture's {wave.temperature_c:.2f} degC"
            )
            wave = dataclasses.replace(wave, temperature_c=d.temperature_c)
    freqs = sorted({x.frequency_hz for x in (lobe, wave) if x is not None})
    if len(freqs) > 1:
        raise cfg.error(
            "data",
            f"the lobe and wave files were captured at different frequencies {freqs} Hz; "
            "fix: fit data of one drive frequency",
        )
    temps = [x.temperature_c for x in (lobe, wave) if x is not None]
    _unwise_data_warnings(cfg, lobe, wave)
    return FitData(
        lobe=lobe,
        wave=wave,
        paths=tuple(paths),
        notes=tuple(notes),
        frequency_hz=freqs[0],
        temperature_c=float(np.mean(temps)),
    )


def _symmetric_model(m: ModelSection) -> bool:
    if m.model == "disc":  # symmetric about its axis by construction
        return True
    return all(p in ("uniform", "symmetric") or (p == "smooth" and m.symmetric) for p in (m.weights, m.lags))


def _unwise_data_warnings(cfg: FitConfig, lobe, wave) -> None:
    from .data import floor_limited_level_db, one_sided

    if lobe is not None:
        bottom = floor_limited_level_db(lobe)
        span = None if bottom is None else float(np.max(lobe.level_db)) - bottom
        if span is not None and cfg.solver.floor_db > span:
            warnings.warn(
                message(
                    cfg.path,
                    "solver.floor_db",
                    None,
                    f"= {show(cfg.solver.floor_db)} dB reaches below the data's dynamic range ({span:.1f} dB "
                    "from the peak to the noise floor or clipped bottom of the lobe data): the nulls "
                    f"there are fitted at face value; use floor_db <= {max(span - 3, 1):.0f}",
                ),
                ConfigWarning,
                stacklevel=3,
            )
    sides = [
        v
        for v in ((lobe.angle_deg if lobe is not None else None), (wave.x_m if wave is not None else None))
        if v is not None
    ]
    if sides and all(one_sided(v) for v in sides) and not _symmetric_model(cfg.model):
        warnings.warn(
            message(
                cfg.path,
                "model",
                None,
                "the data cover one side of the axis only, but the model is not symmetric (weights = "
                f"{show(cfg.model.weights)}, lags = {show(cfg.model.lags)}, symmetric = "
                f"{show(cfg.model.symmetric)}): its other half is not determined; use symmetric profiles",
            ),
            ConfigWarning,
            stacklevel=3,
        )
