"""Work-precision: error against run time over a sweep of resolutions, against analytic references.

Three built-in cases (`difflattice accuracy --case ...`): "polaroid" (below), "wall" (a point
source's echo from a flat rigid or soft wall against the image-source solution: `run_wall`,
`wall_sweep`) and "edges" (the reflection of the window's absorbing edges against a window too
large to reach: `edge_sweep`).

Case "polaroid": a uniform line source as long as the Polaroid's face (35.7 mm, 50 kHz,
air at 343 m/s), modelled as on the fitting path (one simulated cell + translation + far-field
transform / scan-line phasors). References, computed independently of the lattice:

- lobe at 1 m: the continuous uniform line, p(theta) = integral over the face of
  H0(k R) dy (scipy Hankel function, Gauss-Legendre quadrature, exact range);
- near-field wavefront at z = 16.5 mm: the same integral at the scan points; arrival time from the
  phase (fraction of a period).

Errors reported: max |dB| difference over the main lobe and first side lobes (reference above
-20 dB), first-null angle (deg), wavefront arrival (max over |x| <= 10 mm, in periods), and the
wall time of the transfer computation. The reference line has the modelled length (a whole number
of cells), so the errors do not include rounding the face length to cells. They do include
sampling the face by n point cells (a midpoint rule: about 0.11 dB x (6 / cells per wavelength)^2
of lobe error for any solver that models the face as n cells; measured against the discrete
array of the same n point sources in benchmarks/jwave_compare.py, which isolates the solver's
own error).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from ..observe.analytic import phase_error_rad

if TYPE_CHECKING:
    from ..lattice.grid import StencilKind

Dtype = Literal["float32", "float64"]
Backend = Literal["auto", "jax", "native"]

F_HZ, C_M_S, FACE_M, Z_M = 50e3, 343.0, 0.0357, 0.0165


class RowPrinter:
    """Prints result rows as an aligned console table (header once), not as dicts: `columns` are
    (key, header, format) triples; a missing or None value prints as "-"."""

    def __init__(self, columns):
        self.columns = columns
        self.widths = [max(len(h), 8) for _, h, _ in columns]
        self.started = False

    def __call__(self, row: dict) -> None:
        if not self.started:
            print("  ".join(h.rjust(w) for (_, h, _), w in zip(self.columns, self.widths)), flush=True)
            self.started = True
        cells = []
        for (k, _, fmt), w in zip(self.columns, self.widths):
            v = row.get(k)
            cells.append(("-" if v is None else format(v, fmt)).rjust(w))
        print("  ".join(cells), flush=True)


_POLAROID_COLUMNS = [
    ("cells_per_wavelength", "cells/λ", "g"),
    ("dtype", "dtype", "s"),
    ("farfield_dispersion", "far-field k", "s"),
    ("n_cells", "cells", "d"),
    ("wall_time_s", "time (s)", ".3f"),
    ("lobe_db_max_error", "lobe err (dB)", ".3f"),
    ("first_null_error_deg", "null err (deg)", ".3f"),
    ("arrival_error_periods", "arrival err (periods)", ".4f"),
]
_WALL_COLUMNS = [
    ("case", "case", "s"),
    ("cells_per_wavelength", "cells/λ", "g"),
    ("dtype", "dtype", "s"),
    ("wall_time_s", "time (s)", ".3f"),
    ("field_rel_l2_error", "field err (rel L2)", ".4f"),
    ("pattern_db_max_error", "pattern err (dB)", ".3f"),
    ("echo_arrival_error_periods", "echo arrival (periods)", ".4f"),
    ("echo_amplitude_db_error", "echo level (dB)", ".3f"),
]
_EDGE_COLUMNS = [
    ("cells_per_wavelength", "cells/λ", "g"),
    ("dtype", "dtype", "s"),
    ("edge", "edge", "s"),
    ("thickness_cells", "cells", "d"),
    ("wall_time_s", "time (s)", ".3f"),
    ("reflection_db_axis", "axis (dB)", ".1f"),
    ("reflection_db_corner", "corner (dB)", ".1f"),
]
_FIT_COLUMNS = [
    ("cells_per_wavelength", "cells/λ", "g"),
    ("wall_time_s", "time (s)", ".1f"),
    ("converged", "converged", ""),
    ("chi2_reduced", "chi2_red", ".3g"),
    ("diameter_mm", "D (mm)", ".3f"),
    ("diameter_stderr_mm", "± (mm)", ".3f"),
    ("edge_lag_us", "edge lag (µs)", ".3f"),
]


def reference(angles_deg, x_m, *, length_m: float = FACE_M, range_m: float = 1.0, n_quad: int = 4000):
    """Continuous uniform line source along y of length `length_m`: complex field at the lobe
    points and on the wavefront line (2-D Green's function (i/4) H0(kR), exp(-i omega t))."""
    from scipy.special import hankel1

    k = 2 * math.pi * F_HZ / C_M_S
    yq, wq = np.polynomial.legendre.leggauss(n_quad)
    yq, wq = yq * length_m / 2, wq * length_m / 2
    th = np.radians(angles_deg)
    ox, oy = range_m * np.cos(th), range_m * np.sin(th)
    R = np.hypot(ox[:, None], oy[:, None] - yq[None, :])
    lobe = (0.25j * hankel1(0, k * R)) @ wq
    R2 = np.hypot(Z_M, np.asarray(x_m)[:, None] - yq[None, :])
    wave = (0.25j * hankel1(0, k * R2)) @ wq
    return lobe, wave


def _present(block):
    """A transfer block the sweep asked for (the transfer returns None for blocks not requested)."""
    if block is None:
        raise ValueError("the transfer has no lobe or wavefront block: request both (lobe_range_m, wave_z_m)")
    return block


def _metrics(angles, x_m, lobe, wave, ref_lobe, ref_wave) -> dict:
    from ..observe.observables import lobe_metrics

    ld = 20 * np.log10(np.abs(lobe) / np.abs(lobe).max())
    rd = 20 * np.log10(np.abs(ref_lobe) / np.abs(ref_lobe).max())
    main = rd > -20
    m, r = lobe_metrics(angles, ld), lobe_metrics(angles, rd)
    if m["first_null_deg"] is None or r["first_null_deg"] is None:
        raise ValueError("no first null in the lobe or its reference: widen the angle range past the first null")
    ph = np.unwrap(np.angle(wave))
    rph = np.unwrap(np.angle(ref_wave))
    c = len(x_m) // 2
    inner = np.abs(x_m) <= 0.010
    arr = ((ph - ph[c]) - (rph - rph[c]))[inner] / (2 * math.pi)
    return {
        "lobe_db_max_error": float(np.abs(ld - rd)[main].max()),
        "first_null_error_deg": float(abs(m["first_null_deg"] - r["first_null_deg"])),
        "arrival_error_periods": float(np.abs(arr).max()),
    }


def _need_x64(dtypes) -> None:
    """Precision is the caller's (the CLI turns float64 on for the process): a float64 case without
    it would silently run in float32."""
    import jax

    if "float64" in tuple(dtypes) and not jax.config.read("jax_enable_x64"):
        raise ValueError(
            "dtype float64 needs 64-bit JAX: call jax.config.update('jax_enable_x64', True) at the start of "
            "the program (the `difflattice` command does), or use dtype float32"
        )


def sweep(cells_per_wavelength=(6, 8, 10, 14, 20, 28, 40), dtypes=("float32", "float64"), *, repeats: int = 1) -> dict:
    _need_x64(dtypes)
    from ..fit.transfer import free_field_transfer

    angles = np.arange(0, 60.001, 0.05)
    x_m = np.arange(-0.02, 0.02001, 0.0005)
    rows = []
    refs = {}
    show = RowPrinter(_POLAROID_COLUMNS)
    for dtype in dtypes:
        for ppw in cells_per_wavelength:
            dx = C_M_S / (F_HZ * ppw)
            n = max(2, int(round(FACE_M / dx)))
            # the reference is the continuous line of the modelled length n dx: the comparison
            # measures the scheme's error, not the rounding of the face to whole cells
            if n * dx not in refs:
                refs[n * dx] = reference(angles, x_m, length_m=n * dx)
            ref_lobe, ref_wave = refs[n * dx]
            for disp in ("continuum", "lattice"):
                times = []
                for _ in range(repeats + 1):  # the first run compiles
                    t0 = time.perf_counter()
                    T = free_field_transfer(
                        frequency_hz=F_HZ,
                        c_m_s=C_M_S,
                        n_cells=n,
                        cells_per_wavelength=ppw,
                        lobe_angle_deg=angles,
                        lobe_range_m=1.0,
                        wave_x_m=x_m,
                        wave_z_m=Z_M,
                        dtype=dtype,
                        dispersion=disp,
                    )
                    times.append(time.perf_counter() - t0)
                a = np.ones(n)
                row = {
                    "cells_per_wavelength": ppw,
                    "dtype": dtype,
                    "farfield_dispersion": disp,
                    "n_cells": n,
                    "wall_time_s": float(np.median(times[1:])),
                    "simulation_s": T.info["simulation_s"],
                    **_metrics(angles, x_m, _present(T.lobe) @ a, _present(T.wave) @ a, ref_lobe, ref_wave),
                }
                rows.append(row)
                show(row)
    return {"case": "polaroid uniform line, 35.7 mm, 50 kHz", "rows": rows}


def write(results: dict, out_dir: str | Path) -> None:
    import matplotlib.pyplot as plt

    from .. import plots  # noqa: F401  (sets the backend)

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "accuracy.json").write_text(json.dumps(results, indent=2))
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    keys = [
        ("lobe_db_max_error", "lobe error (dB)"),
        ("first_null_error_deg", "first-null error (deg)"),
        ("arrival_error_periods", "arrival error (periods)"),
    ]
    for ax, (k, lab) in zip(axes, keys):
        for dtype in ("float32", "float64"):
            for disp, style in (("continuum", "-o"), ("lattice", "--s")):
                rs = [r for r in results["rows"] if r["dtype"] == dtype and r["farfield_dispersion"] == disp]
                if rs:
                    ax.loglog(
                        [r["wall_time_s"] for r in rs], [max(r[k], 1e-6) for r in rs], style, label=f"{dtype}, {disp}"
                    )
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel(lab)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    plots.save(fig, out / "accuracy.png")
    lines = [
        "| cells/λ | dtype | far-field k | cells | time (s) | lobe err (dB) | null err (deg) | arrival err (periods) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r['cells_per_wavelength']} | {r['dtype']} | {r['farfield_dispersion']} | {r['n_cells']} | {r['wall_time_s']:.2f} | "
            f"{r['lobe_db_max_error']:.3f} | {r['first_null_error_deg']:.3f} | {r['arrival_error_periods']:.4f} |"
        )
    (out / "accuracy_table.md").write_text("\n".join(lines) + "\n")


def fit_sweep(config_path, out_dir: str | Path, cells_per_wavelength=(8, 10, 14, 20, 28, 40)) -> dict:
    """Run one fit config at a sweep of resolutions: fitted parameters, residuals and time, so a
    user sees the cheapest resolution at which the answer stops changing. Each fit's report goes
    to `out_dir`/ppw<N>."""
    from dataclasses import replace

    from ..fit.config import load_config, run_fit

    base = load_config(config_path)
    rows = []
    show = RowPrinter(_FIT_COLUMNS)
    for ppw in cells_per_wavelength:
        cfg = replace(
            base,
            model=replace(base.model, cells_per_wavelength=float(ppw)),
            output=replace(base.output, field_image=False),
        )
        t0 = time.perf_counter()
        rep = run_fit(cfg, out=Path(out_dir) / f"ppw{ppw}", verbose=False)
        f = rep["fit"]
        rows.append(
            {
                "cells_per_wavelength": ppw,
                "wall_time_s": time.perf_counter() - t0,
                "transfer_s": rep["provenance"]["timing_s"]["transfer_simulation"],
                "converged": f["converged"],
                "chi2_reduced": f["chi2_reduced"],
                "rms": f["rms"],
                "diameter_m": f["parameters"]["diameter_m"],
                "diameter_stderr_m": f["parameters"]["diameter_stderr_m"],
                "edge_lag_s": max(f["parameters"]["lags_s"], key=abs),
            }
        )
        r = rows[-1]
        show(
            {
                **r,
                "diameter_mm": r["diameter_m"] * 1e3,
                "diameter_stderr_mm": r["diameter_stderr_m"] * 1e3,
                "edge_lag_us": r["edge_lag_s"] * 1e6,
            }
        )
    return {"config": str(config_path), "rows": rows}


# ==========================================================================================
# Case "wall": a point source in front of an infinite flat wall (rigid or soft), against the
# image-source solution. Case "edges": the window's absorbing edges against a larger window.
# ==========================================================================================

WALL_DISTANCE_WAVELENGTHS = 4.0
"""Source to wall face, wavelengths."""
BEHIND_WAVELENGTHS = 2.0
"""Free space behind the source (before the absorbing layer), wavelengths."""
HALF_HEIGHT_WAVELENGTHS = 6.0
"""Free space each side of the source along the wall (before the absorbing layer), wavelengths."""
LINE_OFFSET_WAVELENGTHS = 2.0
"""The receiver line runs parallel to the wall this far in front of the source, wavelengths."""
LINE_HALF_LENGTH_WAVELENGTHS = 4.0
PROBE_OFFSET_WAVELENGTHS = 1.0
"""The echo probe sits this far beside the source, along the wall, wavelengths."""
BURST_CYCLES = 4.0


def _green_2d(k, r):
    """(i/4) H0(k r): the 2-D Helmholtz Green's function, (del^2 + k^2) G = -delta, for the
    exp(-i omega t) convention (outgoing)."""
    from scipy.special import hankel1

    return 0.25j * hankel1(0, k * r)


def image_source_reference(omega, c, r_direct, r_image, reflection: float):
    """Continuum field per unit lattice source spectrum of a point source at `r_direct` (cells)
    plus its image at `r_image` with reflection coefficient `reflection` (+1 rigid, -1 soft).

    In lattice units (dx = dt = 1), a soft source adding v(n) to the pressure at step n is the
    source term f(n) = v(n + 1) of p_tt = c^2 del^2 p + f delta(x), so with the DFT
    X(omega) = sum_n x(n) exp(+i omega n): P = exp(-i omega) V G(k r) / c^2, k = omega / c
    (the continuum wavenumber: the reference has no lattice dispersion)."""
    omega = np.asarray(omega, dtype=float)
    k = omega / c
    return np.exp(-1j * omega) / c**2 * (_green_2d(k, r_direct) + reflection * _green_2d(k, r_image))


def reference_time_series(v, c, r_direct, r_image, reflection: float, n_steps: int, pad: int = 8):
    """Pressure at steps 1..n_steps of the image-source solution for the source values v(1..N),
    by FFT (zero-padded `pad` times: the causal response does not wrap round)."""
    n_fft = pad * max(n_steps, len(v))
    vv = np.zeros(n_fft)
    vv[: len(v)] = v  # vv[m] = v(m + 1)
    # numpy's FFT uses exp(-i omega n): the conjugate of image_source_reference's convention
    omega = 2 * math.pi * np.fft.rfftfreq(n_fft)
    w = omega.copy()
    w[0] = 1.0  # DC: the burst has no DC content; avoid H0(0)
    tr = np.conj(image_source_reference(w, c, r_direct, r_image, reflection))
    tr[0] = 0.0
    # vv is v shifted by one step (vv[m] = v(m+1)); p[m] is p(m+1)
    spec = np.fft.rfft(vv) * tr
    p = np.fft.irfft(spec, n_fft)
    return p[:n_steps]


def wall_layout(cells_per_wavelength: float, *, pml_cells: int | None = None) -> dict:
    """Cell layout of the wall case at a resolution (lattice units: positions in cells).

    The wall fills the cells from `wall_cell` to the right edge (a rigid window edge behind it);
    its face is the cell face at x = wall_cell - 1/2 exactly, at every resolution, and the image
    source is the source cell mirrored about that face. The source is 2 wavelengths in front of
    the left absorbing layer, the receiver line 2 wavelengths in front of the source, parallel to
    the wall, the echo probe 1 wavelength beside the source."""
    ppw = float(cells_per_wavelength)
    if not ppw >= 4:
        raise ValueError(f"cells_per_wavelength = {cells_per_wavelength}: the wall case needs >= 4")
    L = int(pml_cells) if pml_cells is not None else max(20, int(round(ppw)))
    i_s = L + int(round(BEHIND_WAVELENGTHS * ppw))
    d_cells = int(round(WALL_DISTANCE_WAVELENGTHS * ppw))
    wall_cell = i_s + d_cells  # face at wall_cell - 1/2: source-face distance d_cells - 1/2
    nx = wall_cell + 2
    half = int(round(HALF_HEIGHT_WAVELENGTHS * ppw))
    j_s = L + half
    ny = 2 * (L + half) + 1
    face_x = wall_cell - 0.5
    line_i = i_s + int(round(LINE_OFFSET_WAVELENGTHS * ppw))
    hl = int(round(LINE_HALF_LENGTH_WAVELENGTHS * ppw))
    line = np.stack([np.full(2 * hl + 1, line_i), np.arange(j_s - hl, j_s + hl + 1)], 1)
    probe = np.array([[i_s, j_s + int(round(PROBE_OFFSET_WAVELENGTHS * ppw))]])
    return {
        "shape": (nx, ny),
        "pml_cells": L,
        "source": (i_s, j_s),
        "wall_cell": wall_cell,
        "face_x_cells": face_x,
        "image": (2 * face_x - i_s, j_s),
        "line": line,
        "probe": probe,
    }


def _distances(cells, src, img):
    c = np.asarray(cells, float)
    return np.hypot(c[:, 0] - src[0], c[:, 1] - src[1]), np.hypot(c[:, 0] - img[0], c[:, 1] - img[1])


def run_wall(
    cells_per_wavelength: float,
    dtype: Dtype = "float32",
    *,
    wall: str = "rigid",
    repeats: int = 1,
    extra_periods: float = 4.0,
    pml_cells: int | None = None,
) -> dict:
    """Simulate the wall case once (after a compiling run, `repeats` timed runs) and compare it
    with the image-source reference. Returns a row of errors and times (see `wall_sweep`)."""
    import jax
    import jax.numpy as jnp

    from ..lattice.coefficients import Edges
    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from ..solver.loop import run
    from ..solver.sensors import Sensors
    from ..solver.sources import PointSources, ToneBurst
    from ..solver.stepper import Stepper

    if wall not in ("rigid", "soft"):
        raise ValueError(f"wall = {wall!r}; allowed: 'rigid' (R = +1), 'soft' (R = -1)")
    _need_x64([dtype])
    lay = wall_layout(cells_per_wavelength, pml_cells=pml_cells)
    nx, ny = lay["shape"]
    grid = make_grid(
        frequency_hz=F_HZ, cells_per_wavelength=cells_per_wavelength, c_max_m_s=C_M_S, shape=(nx, ny), dtype=dtype
    )
    c = grid.courant
    occ = np.zeros((nx, ny))
    occ[lay["wall_cell"] :, :] = 1.0
    dt = grid.jnp_dtype
    wall_map = jnp.asarray(occ, dt)
    medium = Medium(
        sound_speed_m_s=C_M_S,
        density_kg_m3=1.2,
        boundary_model="conservative",
        rigid=wall_map if wall == "rigid" else None,
        soft=wall_map if wall == "soft" else None,
    )
    edges = Edges(x_lo="pml", x_hi="rigid", y_lo="pml", y_hi="pml", thickness_cells=lay["pml_cells"])
    sig = ToneBurst(F_HZ, BURST_CYCLES, "hann", 1.0)
    src = PointSources(cells=np.asarray([lay["source"]]), signal=sig, weights=jnp.ones(1, dt), lags_s=jnp.zeros(1, dt))
    line, probe = lay["line"], lay["probe"]
    sensors = Sensors(probes=probe, phasor_cells=line)
    stepper = Stepper.build(grid, medium, (src,), sensors, edges)
    # long enough for the burst's echo to pass the farthest receiver, plus a tail
    rd, ri = _distances(line, lay["source"], lay["image"])
    lam = cells_per_wavelength
    periods = float(ri.max()) / lam + BURST_CYCLES + extra_periods
    n_steps = int(math.ceil(periods * grid.steps_per_period))
    f = jax.jit(lambda s: run(s, n_steps))
    times = []
    for _ in range(repeats + 1):  # the first run compiles
        t0 = time.perf_counter()
        res = f(stepper)
        jax.block_until_ready(res.phasors)
        times.append(time.perf_counter() - t0)
    R = 1.0 if wall == "rigid" else -1.0
    omega = grid.omega
    n = np.arange(1, n_steps + 1)
    v = np.asarray(sig(n * grid.dt_s), dtype=float)
    V = np.sum(v * np.exp(1j * omega * n))
    ref = V * image_source_reference(omega, c, rd, ri, R)
    sim = np.asarray(res.phasors, dtype=complex)
    rel_l2 = float(np.linalg.norm(sim - ref) / np.linalg.norm(ref))
    # the same reference with the lattice's own wavenumber along each path (dispersion relation):
    # what is left is the error that dispersion does not explain
    ref_k = (
        V
        * np.exp(-1j * omega)
        / c**2
        * (
            _green_2d(_path_k(omega, c, line, lay["source"]), rd)
            + R * _green_2d(_path_k(omega, c, line, lay["image"]), ri)
        )
    )
    rel_l2_k = float(np.linalg.norm(sim - ref_k) / np.linalg.norm(ref))
    predicted_l2 = float(np.linalg.norm(ref_k - ref) / np.linalg.norm(ref))
    ref_db = 20 * np.log10(np.abs(ref) / np.abs(ref).max())
    sim_db = 20 * np.log10(np.abs(sim) / np.abs(sim).max())
    loud = ref_db > -20
    level_db = 20 * np.log10(np.linalg.norm(sim) / np.linalg.norm(ref))
    # echo arrival at the probe: cross-correlation with the reference in a window round the echo
    pd, pi = _distances(probe, lay["source"], lay["image"])
    p_sim = np.asarray(res.probes, dtype=float)[:, 0]
    p_ref = reference_time_series(v, c, pd[0], pi[0], R, n_steps)
    spp = grid.steps_per_period
    t_echo = pi[0] / c  # steps, from the source's start
    centre = t_echo + BURST_CYCLES * spp / 2
    w0, w1 = int(centre - 0.75 * BURST_CYCLES * spp), int(centre + 0.75 * BURST_CYCLES * spp)
    w0 = max(w0, int(pd[0] / c + BURST_CYCLES * spp) + 1)  # after the direct pulse has passed
    w1 = min(w1, n_steps - 1)
    shift = _delay_steps(p_sim[w0:w1], p_ref[w0:w1])
    direct_shift = _delay_steps(p_sim[:w0], p_ref[:w0])
    return {
        "case": f"{wall} wall",
        "cells_per_wavelength": cells_per_wavelength,
        "dtype": dtype,
        "grid_shape": [nx, ny],
        "n_steps": n_steps,
        "wall_time_s": float(np.min(times[1:] or times)),
        "compile_and_run_s": times[0],
        "echo_path_wavelengths": float(pi[0] / lam),
        "field_rel_l2_error": rel_l2,
        "field_rel_l2_error_predicted": predicted_l2,
        "field_rel_l2_error_after_dispersion": rel_l2_k,
        "pattern_db_max_error": float(np.abs(sim_db - ref_db)[loud].max()),
        "level_db_error": float(level_db),
        "echo_arrival_error_steps": float(shift),
        "echo_arrival_error_periods": float(shift / spp),
        "echo_arrival_error_us": float(shift * grid.dt_s * 1e6),
        "direct_arrival_error_periods": float(direct_shift / spp),
        "echo_amplitude_db_error": float(20 * np.log10(np.abs(p_sim[w0:w1]).max() / np.abs(p_ref[w0:w1]).max())),
        "predicted_echo_phase_error_periods": phase_error_rad(cells_per_wavelength, c, float(pi[0] / lam))
        / (2 * math.pi),
        "predicted_echo_delay_periods": echo_delay_periods(omega, c, probe[0], lay["image"]),
        "predicted_echo_group_delay_periods": echo_delay_periods(omega, c, probe[0], lay["image"], group=True),
    }


def _path_k(omega, c, cells, origin):
    """Lattice wavenumber (radians/cell, `analytic.lattice_wavenumber`) along the straight path
    from `origin` to each cell."""
    from ..observe.analytic import lattice_wavenumber

    d = np.asarray(cells, float) - np.asarray(origin, float)
    return lattice_wavenumber(omega, c, np.arctan2(d[:, 1], d[:, 0]))


def echo_delay_periods(omega: float, c: float, cell, image, *, group: bool = False) -> float:
    """Delay (periods) of the lattice echo behind the continuum one at `cell`, from the dispersion
    relation along the path from the image source: the phase delay r (k_lattice - k) / (2 pi), or
    with `group` the group (envelope) delay omega r (dk_lattice/domega - 1/c) / (2 pi). A burst's
    arrival from cross-correlation lies between the two (the carrier peak nearest the phase delay,
    pulled towards the envelope's)."""
    cell = np.asarray(cell, float).reshape(1, 2)
    r = float(np.hypot(*(cell[0] - np.asarray(image, float))))
    if not group:
        return float(r * (_path_k(omega, c, cell, image)[0] - omega / c) / (2 * math.pi))
    h = 1e-4 * omega
    dk = (_path_k(omega + h, c, cell, image)[0] - _path_k(omega - h, c, cell, image)[0]) / (2 * h)
    return float(omega * r * (dk - 1 / c) / (2 * math.pi))


def _delay_steps(sim, ref, upsample: int = 16) -> float:
    """Delay of `sim` behind `ref` in steps (positive: sim late), from the peak of their
    cross-correlation (FFT-upsampled by `upsample`, parabolic peak)."""
    n = len(sim)
    if n < 4:
        return float("nan")
    m = 2 * n
    S, Rr = np.fft.rfft(sim, m), np.fft.rfft(ref, m)
    xc = np.fft.irfft(S * np.conj(Rr), m * upsample)  # lag l at index l*upsample (mod)
    xc = np.roll(xc, m * upsample // 2)
    k = int(np.argmax(xc))
    if 0 < k < len(xc) - 1:
        a, b, cc = xc[k - 1], xc[k], xc[k + 1]
        k = k + 0.5 * (a - cc) / (a - 2 * b + cc)
    return (k - m * upsample // 2) / upsample


EDGE_INTERIOR_HALF_WAVELENGTHS = 4.0
"""Edge case: free space each side of the source inside the absorbing layers, wavelengths."""
EDGE_PROBE_INSET_WAVELENGTHS = 1.0
EDGE_RECORD_PERIODS = 12.0
EDGE_REFERENCE_HALF_WAVELENGTHS = 9.0
"""Reference window half-size (rigid edges): its first edge echo reaches the probes after
2 x 9 - 3 = 15 wavelengths of travel, later than the record."""


def _edge_run(ppw: float, half_cells: int, edges, dtype: Dtype, probes_rel, n_steps: int, repeats: int):
    import jax
    import jax.numpy as jnp

    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from ..solver.loop import run
    from ..solver.sensors import Sensors
    from ..solver.sources import PointSources, ToneBurst
    from ..solver.stepper import Stepper

    L = edges.thickness_cells if edges.kinds() & {"pml", "sponge"} else 0
    n = 2 * (half_cells + L) + 1
    centre = half_cells + L
    grid = make_grid(frequency_hz=F_HZ, cells_per_wavelength=ppw, c_max_m_s=C_M_S, shape=(n, n), dtype=dtype)
    dt = grid.jnp_dtype
    sig = ToneBurst(F_HZ, BURST_CYCLES, "hann", 1.0)
    src = PointSources(
        cells=np.asarray([(centre, centre)]), signal=sig, weights=jnp.ones(1, dt), lags_s=jnp.zeros(1, dt)
    )
    probes = np.asarray(probes_rel) + centre
    stepper = Stepper.build(grid, Medium(sound_speed_m_s=C_M_S), (src,), Sensors(probes=probes), edges)
    f = jax.jit(lambda s: run(s, n_steps))
    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        res = f(stepper)
        jax.block_until_ready(res.probes)
        times.append(time.perf_counter() - t0)
    return np.asarray(res.probes, dtype=float), float(np.min(times[1:] or times)), n


def edge_sweep(
    cells_per_wavelength=(10, 20),
    thicknesses_cells=(5, 10, 20, 40),
    dtype: Dtype = "float32",
    *,
    repeats: int = 1,
    kinds=("pml", "sponge", "mur", "rigid"),
) -> dict:
    """Spurious reflection of each absorbing edge kind (and thickness) against a window so large
    that its edges are not reached in the record (same lattice, same source: the difference is
    the edge's reflection alone). A point source (4-cycle Hann burst) sits 4 wavelengths from the
    layers' inner boundary; probes 1 wavelength inside it on the axis and at the corner diagonal.
    Error: max |p - p_ref| over the record / max |p_ref| at that probe, in dB."""

    from ..lattice.coefficients import Edges

    _need_x64([dtype])
    rows = []
    show = RowPrinter(_EDGE_COLUMNS)
    for ppw in cells_per_wavelength:
        half = int(round(EDGE_INTERIOR_HALF_WAVELENGTHS * ppw))
        inset = int(round(EDGE_PROBE_INSET_WAVELENGTHS * ppw))
        probes_rel = np.array([[half - inset, 0], [half - inset, half - inset]])
        spp = ppw / 0.707
        n_steps = int(math.ceil(EDGE_RECORD_PERIODS * spp))
        ref_half = int(round(EDGE_REFERENCE_HALF_WAVELENGTHS * ppw))
        p_ref, t_ref, n_ref = _edge_run(ppw, ref_half, Edges.all("rigid"), dtype, probes_rel, n_steps, repeats)
        scale = np.abs(p_ref).max(0)
        for kind in kinds:
            ths = thicknesses_cells if kind in ("pml", "sponge") else (0,)
            for L in ths:
                edges = Edges.all(kind, thickness_cells=max(L, 1))
                p, t, n = _edge_run(ppw, half, edges, dtype, probes_rel, n_steps, repeats)
                err = np.abs(p - p_ref).max(0) / scale
                row = {
                    "cells_per_wavelength": ppw,
                    "dtype": dtype,
                    "edge": kind,
                    "thickness_cells": L,
                    "thickness_wavelengths": L / ppw,
                    "grid_cells": n * n,
                    "n_steps": n_steps,
                    "wall_time_s": t,
                    "reflection_db_axis": float(20 * np.log10(max(err[0], 1e-12))),
                    "reflection_db_corner": float(20 * np.log10(max(err[1], 1e-12))),
                }
                rows.append(row)
                show(row)
        rows.append(
            {
                "cells_per_wavelength": ppw,
                "dtype": dtype,
                "edge": "reference (large window)",
                "thickness_cells": 0,
                "thickness_wavelengths": 0.0,
                "grid_cells": n_ref * n_ref,
                "n_steps": n_steps,
                "wall_time_s": t_ref,
                "reflection_db_axis": None,
                "reflection_db_corner": None,
            }
        )
    return {"case": "edges: point source, 4-cycle burst, edges 4 wavelengths away", "rows": rows}


def wall_sweep(
    cells_per_wavelength=(6, 8, 10, 14, 20, 30),
    dtypes=("float32", "float64"),
    walls=("rigid", "soft"),
    *,
    repeats: int = 3,
) -> dict:
    """The wall case (`run_wall`) over a sweep of resolutions, precisions and wall kinds."""
    rows = []
    show = RowPrinter(_WALL_COLUMNS)
    for dtype in dtypes:
        for wall in walls:
            for ppw in cells_per_wavelength:
                row = run_wall(float(ppw), dtype, wall=wall, repeats=repeats)
                rows.append(row)
                show(row)
    return {
        "case": "point source 4 wavelengths in front of an infinite flat wall, 50 kHz, 4-cycle Hann burst; "
        "reference: free field + image source (continuum 2-D Green's function)",
        "rows": rows,
    }


def write_wall(results: dict, out_dir: str | Path) -> None:
    """accuracy_wall.json, accuracy_wall_table.md and accuracy_wall.png (errors against wall time)."""
    import matplotlib.pyplot as plt

    from .. import plots

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "accuracy_wall.json").write_text(json.dumps(results, indent=2))
    keys = [
        ("echo_arrival_error_periods", "echo arrival error (periods)"),
        ("field_rel_l2_error", "field error (relative L2)"),
        ("pattern_db_max_error", "interference pattern error (dB)"),
    ]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for ax, (k, lab) in zip(axes, keys):
        for dtype, marker in (("float32", "o"), ("float64", "s")):
            for wall, style in (("rigid", "-"), ("soft", "--")):
                rs = [r for r in results["rows"] if r["dtype"] == dtype and r["case"] == f"{wall} wall"]
                if rs:
                    ax.loglog(
                        [r["wall_time_s"] for r in rs],
                        [max(abs(r[k]), 1e-6) for r in rs],
                        style + marker,
                        label=f"{wall}, {dtype}",
                        ms=4,
                    )
                    if dtype == "float32" and wall == "rigid":
                        for r in rs:
                            ax.annotate(
                                f"{r['cells_per_wavelength']:g}",
                                (r["wall_time_s"], max(abs(r[k]), 1e-6)),
                                textcoords="offset points",
                                xytext=(4, 4),
                                fontsize=7,
                            )
        if k == "echo_arrival_error_periods":
            rs = [r for r in results["rows"] if r["dtype"] == "float32" and r["case"] == "rigid wall"]
            ax.loglog(
                [r["wall_time_s"] for r in rs],
                [r["predicted_echo_phase_error_periods"] for r in rs],
                ":",
                color="gray",
                label="dispersion relation (worst direction)",
            )
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel(lab)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(
        "wall case: point source 4 λ from a flat wall vs image-source solution (labels: cells per wavelength)",
        fontsize=10,
    )
    fig.tight_layout()
    plots.save(fig, out / "accuracy_wall.png")
    lines = [
        "| wall | dtype | cells/λ | grid | steps | time (s) | echo arrival err (periods) | (µs) | predicted (periods) "
        "| field rel. L2 err | pattern err (dB) | level err (dB) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r['case'].split()[0]} | {r['dtype']} | {r['cells_per_wavelength']:g} | {r['grid_shape'][0]} x {r['grid_shape'][1]} "
            f"| {r['n_steps']} | {r['wall_time_s']:.3f} | {r['echo_arrival_error_periods']:.4f} | {r['echo_arrival_error_us']:.3f} "
            f"| {r['predicted_echo_phase_error_periods']:.4f} | {r['field_rel_l2_error']:.4f} | {r['pattern_db_max_error']:.3f} "
            f"| {r['level_db_error']:+.3f} |"
        )
    (out / "accuracy_wall_table.md").write_text("\n".join(lines) + "\n")


def write_edges(results: dict, out_dir: str | Path) -> None:
    """accuracy_edges.json, accuracy_edges_table.md and accuracy_edges.png."""
    import matplotlib.pyplot as plt

    from .. import plots

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "accuracy_edges.json").write_text(json.dumps(results, indent=2))
    rows = [r for r in results["rows"] if r["reflection_db_axis"] is not None]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ppw, marker in zip(sorted({r["cells_per_wavelength"] for r in rows}), "os^v"):
        for kind, color in (("pml", "tab:blue"), ("sponge", "tab:orange")):
            rs = [r for r in rows if r["edge"] == kind and r["cells_per_wavelength"] == ppw]
            axes[0].plot(
                [r["thickness_wavelengths"] for r in rs],
                [r["reflection_db_corner"] for r in rs],
                "-" + marker,
                color=color,
                label=f"{kind}, {ppw:g} cells/λ",
            )
            axes[1].semilogx(
                [r["wall_time_s"] for r in rs],
                [r["reflection_db_corner"] for r in rs],
                "-" + marker,
                color=color,
                label=f"{kind}, {ppw:g} cells/λ",
            )
        for kind, color in (("mur", "tab:green"), ("rigid", "tab:red")):
            rs = [r for r in rows if r["edge"] == kind and r["cells_per_wavelength"] == ppw]
            for r in rs:
                axes[0].axhline(
                    r["reflection_db_corner"],
                    color=color,
                    ls=":" if marker == "o" else "--",
                    label=f"{kind}, {ppw:g} cells/λ",
                )
                axes[1].semilogx([r["wall_time_s"]], [r["reflection_db_corner"]], marker, color=color)
    axes[0].set_xlabel("layer thickness (wavelengths)")
    axes[1].set_xlabel("wall time (s)")
    for ax in axes:
        ax.set_ylabel("edge reflection at the corner probe (dB re incident)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("window edges: spurious reflection against a window too large to reach", fontsize=10)
    fig.tight_layout()
    plots.save(fig, out / "accuracy_edges.png")
    lines = [
        "| cells/λ | edge | thickness (cells) | (λ) | grid cells | time (s) | reflection on axis (dB) | at the corner (dB) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        ax_db = "—" if r["reflection_db_axis"] is None else f"{r['reflection_db_axis']:.1f}"
        co_db = "—" if r["reflection_db_corner"] is None else f"{r['reflection_db_corner']:.1f}"
        lines.append(
            f"| {r['cells_per_wavelength']:g} | {r['edge']} | {r['thickness_cells']} | {r['thickness_wavelengths']:.2f} "
            f"| {r['grid_cells']} | {r['wall_time_s']:.3f} | {ax_db} | {co_db} |"
        )
    (out / "accuracy_edges_table.md").write_text("\n".join(lines) + "\n")


# ==========================================================================================
# Case "piston" (issue 12): a circular piston in a rigid baffle on the axisymmetric (rz)
# lattice, continuous wave, against the exact on-axis field, the far-field lobe 2 J1(x)/x and a
# Rayleigh-integral quadrature on the scan line (all in `observe.analytic`, independent of the
# lattice).
# ==========================================================================================

PISTON_RADIUS_M = 0.0192
"""The Polaroid's 38.4 mm face."""
PISTON_LINE_Z_M = 0.0165
"""The rig's scan line, metres in front of the face."""
PISTON_LINE_X_M = np.round(np.arange(-0.030, 0.030001, 0.0005), 6)
PISTON_LINE_HALF_M = 0.020
"""Line metrics over |x| <= this (the scan the fits use)."""
PISTON_RHO_KG_M3 = 1.2
PISTON_R_MARGIN_WAVELENGTHS = 4.0
PISTON_SETTLE_PERIODS = 20
PISTON_RECORD_PERIODS = 10

_PISTON_COLUMNS = [
    ("stencil", "stencil", "s"),
    ("cells_per_wavelength", "cells/λ", "g"),
    ("frequency_khz", "kHz", "g"),
    ("wall_time_s", "time (s)", ".2f"),
    ("axis_rms_error", "axis RMS", ".4f"),
    ("axis_extrema_error_cells", "extrema (cells)", ".2f"),
    ("null_error_deg", "null (deg)", ".4f"),
    ("sidelobe_error_db", "side lobe (dB)", ".3f"),
    ("line_phase_rms_deg", "line phase (deg)", ".2f"),
    ("line_amp_rms_db", "line amp (dB)", ".3f"),
]


def piston_courant(cells_per_wavelength: float, stencil: StencilKind = "standard") -> float:
    """The lattice speed giving a whole number of steps per period just below the stability limit
    of `stencil` (cells/step): the steady-state phasors then have no DFT leakage."""
    from ..lattice.grid import stability_limit

    limit = stability_limit("rz", stencil)
    return cells_per_wavelength / math.ceil(cells_per_wavelength / limit - 1e-9)


def run_piston(
    cells_per_wavelength: float,
    *,
    frequency_hz: float = F_HZ,
    radius_m: float = PISTON_RADIUS_M,
    c_m_s: float = C_M_S,
    on_axis: bool = True,
    line_z_m: float = PISTON_LINE_Z_M,
    line_x_m=PISTON_LINE_X_M,
    dtype: Dtype = "float64",
    pml_cells: int = 20,
    repeats: int = 1,
    stencil: StencilKind = "standard",
    backend: Backend = "auto",
) -> dict:
    """One continuous-wave run of a baffled piston (face at z = 0 on the rigid z_lo window face,
    PML on the outer radius and z_hi) until steady, then phasors over whole periods. Returns the
    complex amplitudes (per rho c u0: the drive's amplitude is rho c u0 = 1 Pa) on the axis (row
    centres from 0 to 5 a^2 / lambda, if `on_axis`), on the scan line and the far-field patterns
    (both transforms), the layout and the run time (median of `repeats` after a compiling run)."""
    import jax
    import jax.numpy as jnp

    from ..lattice.coefficients import Edges
    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from ..observe.farfield_rz import CylinderSurface, axis_line, far_field_rz, scan_line
    from ..solver.loop import run
    from ..solver.sensors import Sensors
    from ..solver.sources import ContinuousWave, disc_transducer
    from ..solver.stepper import Stepper

    _need_x64([dtype])
    ppw = float(cells_per_wavelength)
    lam = c_m_s / frequency_hz
    dx = lam / ppw
    a_cells = radius_m / dx
    courant = piston_courant(ppw, stencil)
    spp = int(round(ppw / courant))
    gap = max(3, math.ceil(ppw / 2))  # the far-field cylinder: half a wavelength around the face
    z_far = 5 * radius_m**2 / lam if on_axis else line_z_m
    nz = math.ceil(max(z_far, line_z_m, (gap + 2) * dx) / dx + 2 * ppw) + pml_cells
    nr = math.ceil(max(a_cells, np.abs(line_x_m).max() / dx) + PISTON_R_MARGIN_WAVELENGTHS * ppw) + pml_cells
    grid = make_grid(
        frequency_hz=frequency_hz,
        cells_per_wavelength=ppw,
        c_max_m_s=c_m_s,
        shape=(nz, nr),
        courant=courant,
        dtype=dtype,
        kind="rz",
        stencil=stencil,
    )
    src = disc_transducer(grid, radius_m=radius_m, signal=ContinuousWave(frequency_hz, 3.0, 1.0))
    surface = CylinderSurface(0, gap, math.ceil(a_cells) + gap, baffled=True)
    surface.check_inside(grid, margin=pml_cells)
    line = scan_line(grid, line_x_m, line_z_m)
    groups = [("surface", surface.cells), ("line", line.cells)]
    axis = None
    if on_axis:
        z_axis = (np.arange(nz - pml_cells - 2) + 0.5) * dx  # row centres (sampled exactly)
        z_axis = z_axis[z_axis >= 2 * dx]
        axis = axis_line(grid, z_axis)
        groups.append(("axis", axis.cells))
    cells = np.concatenate([c for _, c in groups])
    n_settle = math.ceil((math.hypot(nz, nr) / courant + PISTON_SETTLE_PERIODS * spp) / spp) * spp
    n_steps = n_settle + PISTON_RECORD_PERIODS * spp
    sensors = Sensors(phasor_cells=cells, phasor_from_step=n_settle)
    stepper = Stepper.build(
        grid,
        Medium(c_m_s, PISTON_RHO_KG_M3),
        src,
        sensors,
        Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=pml_cells),
    )
    f = jax.jit(lambda s: run(s, n_steps, backend=backend))
    times = []
    for _ in range(repeats + 1):  # the first run compiles
        t0 = time.perf_counter()
        res = f(stepper)
        jax.block_until_ready(res.phasors)
        times.append(time.perf_counter() - t0)
    amp = np.asarray(res.phasors) * 2 / (n_steps - n_settle)  # complex amplitude, p = Re(A exp(-i omega t))
    parts, start = {}, 0
    for name, c in groups:
        parts[name] = jnp.asarray(amp[start : start + len(c)])
        start += len(c)
    out = {
        "cells_per_wavelength": ppw,
        "stencil": stencil,
        "frequency_hz": frequency_hz,
        "radius_m": radius_m,
        "c_m_s": c_m_s,
        "dx_m": dx,
        "courant": courant,
        "steps_per_period": spp,
        "grid_shape": [nz, nr],
        "n_steps": n_steps,
        "wall_time_s": float(np.median(times[1:] or times)),
        "compile_and_run_s": times[0],
        "line_x_m": np.asarray(line_x_m, float),
        "line_z_m": line_z_m,
        "line": np.asarray(line(parts["line"])),
    }
    angles = np.arange(0.0, min(89.0, math.degrees(math.asin(min(1.0, 7.0 / (2 * math.pi / lam * radius_m))))), 0.005)
    out["angles_deg"] = angles
    for disp in ("continuum", "lattice"):
        out[f"far_{disp}"] = np.asarray(far_field_rz(parts["surface"], surface, grid, angles, dispersion=disp))
    if axis is not None:
        out["axis_z_m"] = z_axis
        out["axis"] = np.asarray(axis(parts["axis"]))
    return out


def _extrema(z, y, lo, hi):
    """Positions of the local extrema of y(z) inside (lo, hi), parabola-refined, with their kind."""
    out = []
    for i in range(1, len(y) - 1):
        if lo < z[i] < hi and ((y[i] > y[i - 1] and y[i] >= y[i + 1]) or (y[i] < y[i - 1] and y[i] <= y[i + 1])):
            d = 0.5 * (y[i - 1] - y[i + 1]) / (y[i - 1] - 2 * y[i] + y[i + 1])
            out.append((z[i] + d * (z[1] - z[0]), "max" if y[i] > y[i - 1] else "min"))
    return out


def _refine(x, y, i):
    """Parabola through (x, y)[i-1 .. i+1]: vertex position and value."""
    y0, y1, y2 = y[i - 1], y[i], y[i + 1]
    d = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    return x[i] + d * (x[1] - x[0]), y1 - 0.25 * (y0 - y2) * d


def piston_errors(raw: dict, *, line_half_m: float = PISTON_LINE_HALF_M) -> dict:
    """Errors of a `run_piston` result against the references (exp(-i omega t); the drive is
    u(t) = u0 sin(omega t), complex velocity i u0):

    - on axis, z from a^2 / (4 lambda) to 5 a^2 / lambda: RMS of (|p| - |p_exact|) / (2 rho c u0)
      with the physical k ("axis_rms_error") and against the same two-ray form with the lattice's
      own wavenumbers (`analytic.piston_on_axis_lattice`, "axis_rms_error_lattice_k"); maxima and
      minima positions (cells) against both;
    - far field (continuum and lattice transforms): first null (deg) and first side lobe (dB)
      against 2 J1(ka sin t) / (ka sin t), max |dB| error where the lobe is above -20 dB;
    - the scan line: phase error RMS (deg; absolute, and after removing the mean phase, which
      only shifts the time origin) and amplitude error RMS (dB; over points within 10 dB of the
      line's maximum, and over all points: near a deep null a dB error means little) against
      `analytic.rayleigh_piston`, within |x| <= `line_half_m`; and the largest complex error
      relative to the line's maximum."""
    from ..observe import analytic as an

    k = 2 * math.pi * raw["frequency_hz"] / raw["c_m_s"]
    a = raw["radius_m"]
    lam = 2 * math.pi / k
    dx = raw["dx_m"]
    row = {
        "stencil": raw.get("stencil", "standard"),
        "cells_per_wavelength": raw["cells_per_wavelength"],
        "courant": raw["courant"],
        "frequency_khz": raw["frequency_hz"] / 1e3,
        "grid_shape": raw["grid_shape"],
        "n_steps": raw["n_steps"],
        "wall_time_s": raw["wall_time_s"],
        "mlups": raw["grid_shape"][0] * raw["grid_shape"][1] * raw["n_steps"] / raw["wall_time_s"] / 1e6,
    }
    if "axis" in raw:
        z, p = raw["axis_z_m"], raw["axis"]
        lo, hi = a * a / (4 * lam), 5 * a * a / lam
        sel = (z >= lo) & (z <= hi)
        omega = 2 * math.pi / raw["steps_per_period"]
        ex = np.abs(an.piston_on_axis(z, a, k))
        lk = np.abs(an.piston_on_axis_lattice(z, a, omega, raw["courant"], dx, raw.get("stencil", "standard")))
        row["axis_rms_error"] = float(np.sqrt(np.mean(((np.abs(p) - ex)[sel] / 2) ** 2)))
        row["axis_max_error"] = float(np.abs((np.abs(p) - ex)[sel] / 2).max())
        row["axis_rms_error_lattice_k"] = float(np.sqrt(np.mean(((np.abs(p) - lk)[sel] / 2) ** 2)))
        zf = np.linspace(lo, hi, 400_001)
        sim = _extrema(z, np.abs(p), lo, hi)
        for key, ref_curve in (
            ("", np.abs(an.piston_on_axis(zf, a, k))),
            (
                "_lattice_k",
                np.abs(an.piston_on_axis_lattice(zf, a, omega, raw["courant"], dx, raw.get("stencil", "standard"))),
            ),
        ):
            ref = _extrema(zf, ref_curve, lo, hi)
            errs = []
            for zr, kind in ref:
                cand = [zs for zs, ks in sim if ks == kind]
                errs.append(min((abs(zs - zr) for zs in cand), default=float("inf")) / dx)
            row["axis_extrema_error_cells" + key] = float(max(errs)) if errs else None
            row["axis_extrema" + key] = [
                {"z_mm": zr * 1e3, "kind": kind, "error_cells": e} for (zr, kind), e in zip(ref, errs)
            ]
    ang = raw["angles_deg"]
    ka = k * a
    th_null = math.degrees(math.asin(an.PISTON_FIRST_NULL_KA_SIN / ka))
    th_sl = math.degrees(math.asin(an.PISTON_FIRST_SIDELOBE_KA_SIN / ka))
    ref_db = 20 * np.log10(np.maximum(np.abs(an.piston_directivity(np.radians(ang), ka)), 1e-30))
    for disp in ("continuum", "lattice"):
        F = raw[f"far_{disp}"]
        power = np.abs(F / F[0]) ** 2
        near = np.abs(ang - th_null) < 2.0
        i = int(np.argmin(np.where(near, power, np.inf)))
        tn, _ = _refine(ang, power, i)  # |F|^2 is a parabola at a null
        db = 10 * np.log10(np.maximum(power, 1e-30))
        j = int(np.argmax(np.where(np.abs(ang - th_sl) < 2.0, db, -np.inf)))
        ts, ls = _refine(ang, db, j)
        sfx = "" if disp == "continuum" else "_lattice_k"
        row["null_error_deg" + sfx] = float(tn - th_null)
        row["sidelobe_error_db" + sfx] = float(ls - an.PISTON_FIRST_SIDELOBE_DB)
        row["sidelobe_angle_error_deg" + sfx] = float(ts - th_sl)
        row["lobe_db_max_error" + sfx] = float(np.abs(db - ref_db)[ref_db > -20].max())
    x = raw["line_x_m"]
    ref = 1j * an.rayleigh_piston(np.stack([x, np.full_like(x, raw["line_z_m"])], 1), a, k)
    s = np.abs(x) <= line_half_m + 1e-12
    dph = np.angle(raw["line"][s] / ref[s])
    dph_c = np.angle(np.exp(1j * (dph - np.angle(np.mean(np.exp(1j * dph))))))
    amp = 20 * np.log10(np.abs(raw["line"][s]) / np.abs(ref[s]))
    loud = 20 * np.log10(np.abs(ref[s]) / np.abs(ref[s]).max()) > -10
    row["line_phase_rms_deg"] = float(np.degrees(np.sqrt(np.mean(dph**2))))
    row["line_phase_rms_deg_centred"] = float(np.degrees(np.sqrt(np.mean(dph_c**2))))
    row["line_amp_rms_db"] = float(np.sqrt(np.mean(amp[loud] ** 2)))
    row["line_amp_rms_db_all"] = float(np.sqrt(np.mean(amp**2)))
    row["line_complex_error"] = float(np.abs(raw["line"][s] - ref[s]).max() / np.abs(ref[s]).max())
    return row


def piston_sweep(
    cells_per_wavelength=(6, 8, 10, 14, 20, 28, 40),
    frequencies_hz=(50e3, 40e3),
    *,
    dtype: Dtype = "float64",
    repeats: int = 1,
    stencils=("standard", "isotropic"),
    backend: Backend = "auto",
) -> dict:
    """The piston case over a sweep of resolutions and stencils: the on-axis field at the first
    frequency, the lobe and the scan line at each. `backend` "auto" (default) runs both stencils on
    the native CPU kernels where they apply (both have them: a like-for-like error-against-run-time
    comparison); "jax" times both on the XLA loop."""
    import os

    load_start = os.getloadavg()
    rows = []
    show = RowPrinter(_PISTON_COLUMNS)
    for stencil in stencils:
        for ppw in cells_per_wavelength:
            for i, f in enumerate(frequencies_hz):
                raw = run_piston(
                    float(ppw),
                    frequency_hz=f,
                    on_axis=(i == 0),
                    dtype=dtype,
                    repeats=repeats,
                    stencil=stencil,
                    backend=backend,
                )
                row = piston_errors(raw)
                row["dtype"] = dtype
                row["backend"] = backend
                rows.append(row)
                show(row)
    return {
        "case": f"baffled circular piston, {2e3 * PISTON_RADIUS_M:.1f} mm, continuous wave, rz lattice; references: "
        "exact on-axis field, 2 J1(x)/x, Rayleigh integral at z = 16.5 mm",
        "rows": rows,
        "loadavg_start": load_start,
        "loadavg_end": os.getloadavg(),
    }


def write_piston(results: dict, out_dir: str | Path) -> None:
    """accuracy_piston.json, accuracy_piston_table.md and accuracy_piston.png."""
    import matplotlib.pyplot as plt

    from .. import plots

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "accuracy_piston.json").write_text(json.dumps(results, indent=2))
    keys = [
        ("axis_rms_error", "on-axis RMS error (re 2ρcU)"),
        ("null_error_deg", "|first-null error| (deg)"),
        ("sidelobe_error_db", "|side-lobe error| (dB)"),
        ("line_phase_rms_deg", "line phase RMS (deg)"),
    ]
    fig, axes = plt.subplots(1, 5, figsize=(22, 4.2))
    keys.insert(1, ("axis_extrema_error_cells", "on-axis extrema error (cells)"))
    styles = {
        ("standard", 50.0): "-o",
        ("standard", 40.0): "--s",
        ("isotropic", 50.0): "-^",
        ("isotropic", 40.0): "--v",
    }
    for ax, (k, lab) in zip(axes, keys):
        for (st, f), style in styles.items():
            rs = [
                r
                for r in results["rows"]
                if r["frequency_khz"] == f and r.get("stencil", "standard") == st and r.get(k) is not None
            ]
            if rs:
                ax.loglog(
                    [r["wall_time_s"] for r in rs],
                    [max(abs(r[k]), 1e-6) for r in rs],
                    style,
                    label=f"{st}, {f:g} kHz",
                    ms=4,
                )
                for r in rs:
                    ax.annotate(
                        f"{r['cells_per_wavelength']:g}",
                        (r["wall_time_s"], max(abs(r[k]), 1e-6)),
                        textcoords="offset points",
                        xytext=(4, 4),
                        fontsize=7,
                    )
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel(lab)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("baffled circular piston on the rz lattice (labels: cells per wavelength)", fontsize=10)
    fig.tight_layout()
    plots.save(fig, out / "accuracy_piston.png")
    fmt = lambda v, f: "—" if v is None else format(v, f)
    lines = [
        "| stencil | cells/λ | courant | kHz | grid | steps | time (s) | axis RMS (re 2ρcU) | axis RMS, lattice k "
        "| extrema (cells) | extrema, lattice k | null (deg) | side lobe (dB) | line phase RMS (deg) | centred "
        "| line amp RMS (dB) | all points |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r.get('stencil', 'standard')} | {r['cells_per_wavelength']:g} | {r.get('courant', float('nan')):.3f} "
            f"| {r['frequency_khz']:g} | {r['grid_shape'][0]} x {r['grid_shape'][1]} "
            f"| {r['n_steps']} | {r['wall_time_s']:.2f} | {fmt(r.get('axis_rms_error'), '.4f')} "
            f"| {fmt(r.get('axis_rms_error_lattice_k'), '.4f')} | {fmt(r.get('axis_extrema_error_cells'), '.2f')} "
            f"| {fmt(r.get('axis_extrema_error_cells_lattice_k'), '.2f')} | {r['null_error_deg']:+.4f} "
            f"| {r['sidelobe_error_db']:+.3f} | {r['line_phase_rms_deg']:.2f} | {r['line_phase_rms_deg_centred']:.2f} "
            f"| {r['line_amp_rms_db']:.3f} | {r['line_amp_rms_db_all']:.3f} |"
        )
    (out / "accuracy_piston_table.md").write_text("\n".join(lines) + "\n")
