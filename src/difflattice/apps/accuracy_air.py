"""`difflattice accuracy --case air`: air's absorption and dispersion on the lattice, measured.

A plane wave on a one-cell-wide strip (PML at both ends, rigid sides: the 2-D lattice carries
an exact 1-D wave) driven by a continuous sine; the pressure at two ranges, fitted to a sine of
the drive frequency over a whole steady window, gives the attenuation (from the amplitude ratio,
not from any formula) and the phase speed (from the phase difference). Each row compares them
with ISO 9613-1 (`difflattice.air.absorption_db_per_m`) and with the relaxation model's phase
speed carried through the lattice's own dispersion relation (`AirRelaxation.wavenumber`).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import numpy as np

FREQUENCIES_HZ = (20e3, 40e3, 80e3, 120e3, 200e3)
TEMPERATURES_C = (0.0, 20.0, 40.0)
HUMIDITIES_PCT = (10.0, 50.0, 90.0)
PRESSURE_PA = 101_325.0


@dataclass(frozen=True)
class AirRow:
    """One row of `accuracy_air.json` (SI units; alpha in dB/m)."""

    frequency_hz: float
    temperature_c: float
    humidity_pct: float
    pressure_pa: float
    cells_per_wavelength: float
    alpha_db_per_m_lattice: float
    alpha_db_per_m_iso: float
    alpha_db_per_m_lattice_model: float
    phase_speed_m_s_lattice: float
    phase_speed_m_s_model: float
    phase_speed_m_s_air: float
    alpha_rel_error: float
    phase_speed_rel_error: float


def plane_wave(
    frequency_hz: float,
    temperature_c: float,
    humidity_pct: float,
    pressure_pa: float = PRESSURE_PA,
    *,
    cells_per_wavelength: float = 20.0,
    span_wavelengths: float = 60.0,
    window_periods: float = 40.0,
) -> AirRow:
    """Simulate and measure one plane wave (float64; enables JAX's x64 mode)."""
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    from .. import air
    from ..lattice import Edges
    from ..lattice.coefficients import absorbing_courant
    from ..lattice.grid import make_grid
    from ..lattice.medium import AirConditions
    from ..solver import Sensors, Stepper, run
    from ..solver.sources import ContinuousWave, PointSources

    cond = AirConditions(temperature_c, humidity_pct, pressure_pa)
    c0 = air.speed_of_sound_m_s(temperature_c, humidity_pct, pressure_pa)
    courant = absorbing_courant(frequency_hz, cells_per_wavelength, c0, cond, margin=0.98)
    layer = 40
    span = int(round(span_wavelengths * cells_per_wavelength))
    x_src = layer + 10
    x1 = x_src + int(round(2 * cells_per_wavelength))
    x2 = x1 + span
    nx = x2 + 10 + layer
    grid = make_grid(
        frequency_hz=frequency_hz,
        cells_per_wavelength=cells_per_wavelength,
        c_max_m_s=c0,
        shape=(nx, 1),
        courant=courant,
        dtype="float64",
    )
    edges = Edges(x_lo="pml", x_hi="pml", y_lo="rigid", y_hi="rigid", thickness_cells=layer)
    src = PointSources(
        cells=np.array([[x_src, 0]]),
        signal=ContinuousWave(frequency_hz, ramp_cycles=4.0),
        weights=jnp.ones(1),
        lags_s=jnp.zeros(1),
    )
    sens = Sensors(probes=np.array([[x1, 0], [x2, 0]]))
    steps_per_period = cells_per_wavelength / courant
    settle = (x2 - x_src) / courant + 12 * steps_per_period
    n_steps = int(settle + window_periods * steps_per_period)
    stepper = Stepper.build(grid, cond.medium(), src, sens, edges)
    res = run(stepper, n_steps, backend="jax")
    probes = np.asarray(res.probes)
    n0 = int(settle)
    n = np.arange(n0 + 1, n_steps + 1, dtype=float)
    w = grid.hz_to_lattice_omega(frequency_hz)
    basis = np.stack([np.cos(w * n), np.sin(w * n), np.ones_like(n)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, probes[n0:], rcond=None)
    # p = Re(A exp(-i w n)) with A = c_cos + i c_sin; a wave exp(i (k x - w n)) has A ~ exp(i k x)
    amp = coef[0] + 1j * coef[1]
    ratio = amp[1] / amp[0]  # exp(i k (x2 - x1)), k complex
    dx_cells = x2 - x1
    alpha_np_per_cell = -math.log(abs(ratio)) / dx_cells
    relax = stepper.lattice.relax
    assert relax is not None  # an AirConditions medium always has it
    k_model = relax.wavenumber(w, float(stepper.lattice.c))
    # phase advance over the span, unwrapped onto the model's (exact to << pi: the model is 1e-4 off)
    phase = float(np.angle(ratio))
    turns = round((k_model.real * dx_cells - phase) / (2 * math.pi))
    k_meas = (phase + 2 * math.pi * turns) / dx_cells
    dx_m = grid.dx_m
    omega_si = 2 * math.pi * frequency_hz
    c_lat = omega_si / (k_meas / dx_m)
    c_model = omega_si / (k_model.real / dx_m)
    a_lat = alpha_np_per_cell / dx_m * air.NEPER_TO_DB
    a_iso = air.absorption_db_per_m(frequency_hz, temperature_c, humidity_pct, pressure_pa)
    return AirRow(
        frequency_hz=frequency_hz,
        temperature_c=temperature_c,
        humidity_pct=humidity_pct,
        pressure_pa=pressure_pa,
        cells_per_wavelength=cells_per_wavelength,
        alpha_db_per_m_lattice=a_lat,
        alpha_db_per_m_iso=a_iso,
        alpha_db_per_m_lattice_model=k_model.imag / dx_m * air.NEPER_TO_DB,
        phase_speed_m_s_lattice=c_lat,
        phase_speed_m_s_model=c_model,
        phase_speed_m_s_air=air.phase_speed_m_s(frequency_hz, temperature_c, humidity_pct, pressure_pa),
        alpha_rel_error=a_lat / a_iso - 1,
        phase_speed_rel_error=c_lat / c_model - 1,
    )


RESOLUTIONS = (20.0, 8.0)
FILES = "accuracy_air.json, accuracy_air_point_source.json, accuracy_air_table.md, accuracy_air.png"


def sweep(
    resolutions=RESOLUTIONS,
    frequencies_hz=FREQUENCIES_HZ,
    temperatures_c=TEMPERATURES_C,
    humidities_pct=HUMIDITIES_PCT,
    pressure_pa: float = PRESSURE_PA,
    *,
    quick: bool = False,
) -> list[AirRow]:
    """Every (resolution, frequency, temperature, humidity) of the grid, one plane wave each
    (`quick`: shorter spans, for tests)."""
    kw = {"span_wavelengths": 20.0, "window_periods": 20.0} if quick else {}
    return [
        plane_wave(f, t, h, pressure_pa, cells_per_wavelength=float(cpw), **kw)
        for cpw in resolutions
        for f in frequencies_hz
        for t in temperatures_c
        for h in humidities_pct
    ]


def summary(rows: list[AirRow]) -> dict:
    """Worst errors per resolution: attenuation against ISO, phase speed against the model."""
    out = {}
    for cpw in sorted({r.cells_per_wavelength for r in rows}, reverse=True):
        sel = [r for r in rows if r.cells_per_wavelength == cpw]
        out[f"{cpw:g}"] = {
            "rows": len(sel),
            "max_abs_alpha_rel_error": max(abs(r.alpha_rel_error) for r in sel),
            "max_abs_alpha_rel_error_vs_lattice_model": max(
                abs(r.alpha_db_per_m_lattice / r.alpha_db_per_m_lattice_model - 1) for r in sel
            ),
            "max_abs_phase_speed_rel_error": max(abs(r.phase_speed_rel_error) for r in sel),
        }
    return out


def write(rows: list[AirRow], out_dir, point: dict | None = None) -> dict[str, str]:
    """DIR/accuracy_air.json (the rows), accuracy_air_table.md and accuracy_air.png; with `point`
    (`point_source`'s result) also accuracy_air_point_source.json and its lines in the table."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    data = [{k: float(v) for k, v in asdict(r).items()} for r in rows]
    (out / "accuracy_air.json").write_text(json.dumps(data, indent=1))
    text = table(rows)
    files = {"json": str(out / "accuracy_air.json"), "table": str(out / "accuracy_air_table.md")}
    if point is not None:
        (out / "accuracy_air_point_source.json").write_text(json.dumps(point, indent=1))
        files["point_source"] = str(out / "accuracy_air_point_source.json")
        text += point_table(point)
    (out / "accuracy_air_table.md").write_text(text)
    _plot(rows, out / "accuracy_air.png")
    return files


def point_table(pt: dict) -> str:
    lines = [
        "",
        f"## Point source on the rz axis, {pt['frequency_hz'] / 1e3:g} kHz, {pt['temperature_c']:g} °C, "
        f"{pt['humidity_pct']:g} % RH, {pt['cells_per_wavelength']:g} cells/λ, grid {pt['grid_shape']}",
        "",
        "| r m | level lattice dB | 20log(r0/r) - α(r-r0) dB | error dB | absorption lattice dB | -α(r-r0) dB | error dB |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i, r in enumerate(pt["range_m"]):
        lines.append(
            f"| {r:.3f} | {pt['level_db_lattice'][i]:.3f} | {pt['level_db_reference'][i]:.3f} | "
            f"{pt['error_db'][i]:+.3f} | {pt['absorption_db_lattice'][i]:.3f} | {pt['absorption_db_iso'][i]:.3f} | "
            f"{pt['absorption_error_db'][i]:+.3f} |"
        )
    lines.append("")
    lines.append(
        "absorption lattice = level with air absorption minus the same run lossless (the lattice's own "
        "spreading, dispersion and edge reflections cancel)."
    )
    return "\n".join(lines) + "\n"


def table(rows: list[AirRow]) -> str:
    lines = [
        "# Air absorption on the lattice: measured plane waves vs ISO 9613-1",
        "",
        "alpha measured from the amplitudes at two ranges (60 wavelengths apart); phase speed from their",
        "phase difference; model = the relaxation model through the lattice's own dispersion relation.",
        "",
        "| cells/λ | f kHz | T °C | RH % | α lattice dB/m | α ISO dB/m | α err % | c lattice m/s | c model m/s | c err % |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.cells_per_wavelength:g} | {r.frequency_hz / 1e3:g} | {r.temperature_c:g} | {r.humidity_pct:g} | "
            f"{r.alpha_db_per_m_lattice:.4f} | {r.alpha_db_per_m_iso:.4f} | {100 * r.alpha_rel_error:+.2f} | "
            f"{r.phase_speed_m_s_lattice:.4f} | {r.phase_speed_m_s_model:.4f} | {100 * r.phase_speed_rel_error:+.2e} |"
        )
    lines += ["", "Worst per resolution:", ""]
    for cpw, s in summary(rows).items():
        lines.append(
            f"- {cpw} cells/λ ({s['rows']} rows): |α/α_ISO - 1| <= {100 * s['max_abs_alpha_rel_error']:.2f} %, "
            f"|α/α_lattice model - 1| <= {s['max_abs_alpha_rel_error_vs_lattice_model']:.1e}, "
            f"|c/c_model - 1| <= {s['max_abs_phase_speed_rel_error']:.1e}"
        )
    return "\n".join(lines) + "\n"


def _plot(rows: list[AirRow], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.2))
    best = max(r.cells_per_wavelength for r in rows)
    conds = sorted({(r.temperature_c, r.humidity_pct) for r in rows})
    for t, h in conds:
        sel = sorted(
            (r for r in rows if (r.temperature_c, r.humidity_pct) == (t, h) and r.cells_per_wavelength == best),
            key=lambda r: r.frequency_hz,
        )
        f = [r.frequency_hz / 1e3 for r in sel]
        (line,) = ax.loglog(f, [r.alpha_db_per_m_iso for r in sel], "-", lw=1)
        ax.loglog(
            f, [r.alpha_db_per_m_lattice for r in sel], "o", ms=3, color=line.get_color(), label=f"{t:g} °C {h:g} %"
        )
    ax.set(
        xlabel="frequency (kHz)",
        ylabel="attenuation (dB/m)",
        title=f"lines ISO 9613-1, dots lattice ({best:g} cells/λ)",
    )
    ax.legend(fontsize=6, ncol=2)
    for cpw in sorted({r.cells_per_wavelength for r in rows}):
        sel = [r for r in rows if r.cells_per_wavelength == cpw]
        bx.semilogx(
            [r.frequency_hz / 1e3 for r in sel],
            [100 * r.alpha_rel_error for r in sel],
            "o",
            ms=3,
            label=f"{cpw:g} cells/λ",
        )
    bx.axhline(5, color="k", lw=0.5, ls="--")
    bx.axhline(-5, color="k", lw=0.5, ls="--")
    bx.set(xlabel="frequency (kHz)", ylabel="lattice / ISO - 1 (%)", title="attenuation error")
    bx.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


POINT_RANGES_M = (0.5, 1.0, 2.0, 4.0)


def point_source(
    frequency_hz: float = 40e3,
    temperature_c: float = 20.0,
    humidity_pct: float = 50.0,
    pressure_pa: float = PRESSURE_PA,
    *,
    cells_per_wavelength: float = 8.0,
    ranges_m=POINT_RANGES_M,
    cycles: float = 20.0,
    radius_m: float = 0.75,
    pad_periods: float = 5.0,
    dtype: Literal["float32", "float64"] = "float64",
) -> dict:
    """A point source on the axis of the rz lattice: the level of a narrow-band burst (its
    spectrum at the drive frequency over the direct arrival) at `ranges_m` on the axis, against
    ``20 log10(r0 / r) - alpha_ISO (r - r0)``, r0 the first range. The window's radius `radius_m`
    is narrow: waves its r_hi PML reflects at grazing incidence reach the axis 2 R^2 / z later than
    the direct burst (33 wavelengths at 4 m for R = 0.75 m), after its window (the 20-cycle burst
    and `pad_periods` either side for its dispersion at 8 cells/λ; a shorter burst or window was
    measured to fail: 4 cycles, R = 0.45 m gave +2.1 dB at 4 m in the lossless twin too). The same
    run without absorption isolates what the absorption does (`absorption_*` keys)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    from .. import air
    from ..lattice import Edges
    from ..lattice.coefficients import absorbing_courant
    from ..lattice.grid import make_grid
    from ..lattice.medium import AirConditions
    from ..solver import Sensors, Stepper, run
    from ..solver.sources import PointSources, ToneBurst

    cond = AirConditions(temperature_c, humidity_pct, pressure_pa)
    c0 = air.speed_of_sound_m_s(temperature_c, humidity_pct, pressure_pa)
    courant = absorbing_courant(frequency_hz, cells_per_wavelength, c0, cond, kind="rz", margin=0.98)
    dx = c0 / (frequency_hz * cells_per_wavelength)
    layer = 20
    z_src = layer + 10
    span = int(round(max(ranges_m) / dx)) + 1
    nz = z_src + span + 10 + layer
    nr = int(round(radius_m / dx)) + layer
    grid = make_grid(
        frequency_hz=frequency_hz,
        cells_per_wavelength=cells_per_wavelength,
        c_max_m_s=c0,
        shape=(nz, nr),
        courant=courant,
        dtype=dtype,
        kind="rz",
    )
    edges = Edges.axisymmetric(z_lo="pml", z_hi="pml", r_hi="pml", thickness_cells=layer)
    src = PointSources(
        cells=np.array([[z_src, 0]]), signal=ToneBurst(frequency_hz, cycles), weights=jnp.ones(1), lags_s=jnp.zeros(1)
    )
    cells = [z_src + int(round(r / dx)) for r in ranges_m]
    sens = Sensors(probes=np.array([[i, 0] for i in cells]))
    steps_per_period = cells_per_wavelength / courant
    w = grid.hz_to_lattice_omega(frequency_hz)
    # the burst travels at the lattice's group speed along the axis (1-D relation of the standard
    # stencil, sin(w/2) = c sin(k/2)): v_g = c cos(k/2) / cos(w/2) cells/step
    k = 2 * np.arcsin(np.sin(w / 2) / courant)
    v_g = courant * np.cos(k / 2) / np.cos(w / 2)
    burst = cycles * steps_per_period
    pad = pad_periods * steps_per_period

    def window(i):  # the direct arrival at axis cell i, +- pad_periods (the burst's dispersed tails)
        centre = (i - z_src) / v_g + burst / 2
        return max(1, int(centre - burst / 2 - pad)), int(centre + burst / 2 + pad)

    n_steps = window(cells[-1])[1] + 1

    def levels(medium) -> np.ndarray:
        """dB re the first range: the spectrum at the drive frequency of the whole direct arrival
        at each range (the ratio between ranges is the transfer function at f)."""
        stepper = Stepper.build(grid, medium, src, sens, edges)
        probes = np.asarray(run(stepper, n_steps, backend="jax").probes)
        out = []
        for j, i in enumerate(cells):
            n = np.arange(*window(i))
            out.append(20 * np.log10(abs(np.sum(probes[n - 1, j] * np.exp(1j * w * n)))))
        return np.array(out) - out[0]

    absorbing = cond.medium()
    lossless = eqx.tree_at(lambda m: m.air, absorbing, None, is_leaf=lambda x: x is None)
    got, got0 = levels(absorbing), levels(lossless)
    r = np.array([(i - z_src) * dx for i in cells])
    a_iso = air.absorption_db_per_m(frequency_hz, temperature_c, humidity_pct, pressure_pa)
    spread = 20 * np.log10(r[0] / r)
    loss_iso = -a_iso * (r - r[0])
    return {
        "frequency_hz": frequency_hz,
        "temperature_c": temperature_c,
        "humidity_pct": humidity_pct,
        "pressure_pa": pressure_pa,
        "cells_per_wavelength": cells_per_wavelength,
        "grid_shape": list(grid.shape),
        "n_steps": n_steps,
        "alpha_db_per_m_iso": a_iso,
        "range_m": r.tolist(),
        "level_db_lattice": got.tolist(),
        "level_db_reference": (spread + loss_iso).tolist(),
        "error_db": (got - spread - loss_iso).tolist(),
        "level_db_lattice_lossless": got0.tolist(),
        "absorption_db_lattice": (got - got0).tolist(),
        "absorption_db_iso": loss_iso.tolist(),
        "absorption_error_db": (got - got0 - loss_iso).tolist(),
    }
