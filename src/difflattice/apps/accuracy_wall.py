"""Work-precision, cases "wall" and "edges" (`difflattice accuracy --case wall|edges`): a point
source's echo from a flat rigid or soft wall against the image-source solution (`run_wall`,
`wall_sweep`), and the reflection of the window's absorbing edges against a window too large to
reach (`edge_sweep`). The shared table printer and constants are `apps.accuracy`'s."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..observe.analytic import phase_error_rad
from .accuracy import _EDGE_COLUMNS, _WALL_COLUMNS, C_M_S, F_HZ, Dtype, RowPrinter, _need_x64

if TYPE_CHECKING:
    pass


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
    v = np.asarray(sig(np.arange(1, n_steps + 1) * grid.dt_s), dtype=float)
    field = _field_errors(np.asarray(res.phasors, dtype=complex), v, grid, lay, R)
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
        **field,
        "echo_arrival_error_steps": float(shift),
        "echo_arrival_error_periods": float(shift / spp),
        "echo_arrival_error_us": float(shift * grid.dt_s * 1e6),
        "direct_arrival_error_periods": float(direct_shift / spp),
        "echo_amplitude_db_error": float(20 * np.log10(np.abs(p_sim[w0:w1]).max() / np.abs(p_ref[w0:w1]).max())),
        "predicted_echo_phase_error_periods": phase_error_rad(cells_per_wavelength, c, float(pi[0] / lam))
        / (2 * math.pi),
        "predicted_echo_delay_periods": echo_delay_periods(grid.omega, c, probe[0], lay["image"]),
        "predicted_echo_group_delay_periods": echo_delay_periods(grid.omega, c, probe[0], lay["image"], group=True),
    }


def _field_errors(sim: np.ndarray, v: np.ndarray, grid, lay: dict, R: float) -> dict:
    """The line's phasors (`sim`) against the image-source reference of the drive `v`: relative L2
    error, the part the lattice's dispersion predicts, the pattern and level errors (dB)."""
    c, omega, line = grid.courant, grid.omega, lay["line"]
    n = np.arange(1, len(v) + 1)
    V = np.sum(v * np.exp(1j * omega * n))
    rd, ri = _distances(line, lay["source"], lay["image"])
    ref = V * image_source_reference(omega, c, rd, ri, R)
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
    ref_db = 20 * np.log10(np.abs(ref) / np.abs(ref).max())
    sim_db = 20 * np.log10(np.abs(sim) / np.abs(sim).max())
    loud = ref_db > -20
    return {
        "field_rel_l2_error": rel_l2,
        "field_rel_l2_error_predicted": float(np.linalg.norm(ref_k - ref) / np.linalg.norm(ref)),
        "field_rel_l2_error_after_dispersion": float(np.linalg.norm(sim - ref_k) / np.linalg.norm(ref)),
        "pattern_db_max_error": float(np.abs(sim_db - ref_db)[loud].max()),
        "level_db_error": float(20 * np.log10(np.linalg.norm(sim) / np.linalg.norm(ref))),
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
    from ..lattice.window import Span
    from ..solver.loop import run
    from ..solver.sensors import Sensors
    from ..solver.sources import PointSources, ToneBurst
    from ..solver.stepper import Stepper

    L = edges.thickness_cells if edges.kinds() & {"pml", "sponge"} else 0
    span = Span.open(gap=half_cells, layer=L, pad=0)  # free space `half_cells` each side of the source
    n, centre = span.n, span.source
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
