"""j-Wave against difflattice at equal lobe accuracy (issue 5).

    python3 benchmarks/jwave_compare.py [--quick] [--repeats 3] [--no-write]

One command. Creates `.venv-jwave` if missing (`python3 -m venv .venv-jwave &&
.venv-jwave/bin/pip install jwave`; pip picks the jax/jaxlib that jwave 0.2.1 allows: jax 0.4.38
here), then runs, one after the other, each in its own process and venv:

1. reference (`.venv`, cached in out/jwave_compare_reference.json): for every n used below, the
   lobe at 1 m (0..60 deg, 0.05 deg) of (a) the continuous uniform line of length n dx, from
   `difflattice.apps.accuracy.reference` (accuracy.py's reference), and (b) the discrete array of the
   n isotropic point sources dx apart (exact 2-D Green's function, scipy), which isolates the
   solver's error from that of replacing the face by n cells;
2. j-Wave (`.venv-jwave`): `difflattice.apps.accuracy`'s problem (35.7 mm line, 50 kHz, c = 343 m/s,
   n = round(35.7 mm / dx) sources one dx apart) with the pseudo-spectral k-space solver
   `jwave.acoustics.simulate_wave_propagation` (default PML, 20 points; float32), a 4-cycle Hann
   tone burst (as difflattice's transfer runs), the 50 kHz phasor of the whole field taken inside
   the jitted function, then a Kirchhoff-Helmholtz transform to 1 m from a box around the
   source(s) (continuum k, 4-term Hankel expansion as difflattice.observe.farfield), with the spectral p
   and grad p of j-Wave's field FFT-resampled to >= 16 samples per wavelength. Each source cell is
   an isotropic Gaussian mass source (sigma 1.2 cells): a single-grid-point source is a sinc x
   sinc in a pseudo-spectral code and its tails cross the contour (see NOTES). Series:
   "line" (the whole line simulated), "cell" (one source, its contour field translated over the n
   cell positions: difflattice's fast path with the solver swapped), both at CFL 0.3
   (TimeAxis.from_medium's default), and "line" at CFL 0.6;
3. difflattice (`.venv`): `difflattice.apps.accuracy.sweep` at 6..40 cells per wavelength, float32
   (the official sweep; its times include the wavefront block; its "lattice" far-field rows, the
   lattice's own dispersion over 1 m, feed the projection below), and lobe-only runs of the same
   `free_field_transfer` call ("continuum" far field) up to 20 cells per wavelength, float32 and
   float64;
4. throughput on the kernel benchmark's 840x630 grid (float32, PML 20, 200 steps): j-Wave, and
   difflattice in homogeneous air with PML edges (as the kernel benchmark's "homogeneous+pml"
   case), same session; with the
   equal-accuracy resolutions it gives a projected (not measured) cost ratio for a direct
   full-domain simulation out to 1 m.

Error: max |dB| difference of the lobe (dB re its maximum) over the directions where the
reference is above -20 dB (main lobe and first side lobes), as accuracy.py; RMS over the same
directions as well. Times: median of `--repeats` runs after a compiling run, compile time
separately. Equal accuracy: the cheapest measured resolution of each series at or below 1, 0.5,
0.2, 0.1, 0.05 dB, for total time and for simulation-only time. Writes docs/benchmarks/jwave.json
and jwave.md (not with --no-write).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
JW_VENV = ROOT / ".venv-jwave"
MAIN_PY = ROOT / ".venv" / "bin" / "python"
F_HZ, C_M_S, FACE_M, RANGE_M = 50e3, 343.0, 0.0357, 1.0
ANGLES = (0.0, 60.0, 0.05)
THRESHOLDS_DB = (1.0, 0.5, 0.2, 0.1, 0.05)


def log(*a):
    print(*a, file=sys.stderr, flush=True)


def angles():
    import numpy as np

    return np.arange(ANGLES[0], ANGLES[1] + 1e-3, ANGLES[2])


def ref_key(n: int, dx: float) -> str:
    return f"n={n} dx={dx:.9e}"


def n_cells(ppw: float) -> tuple[int, float]:
    dx = C_M_S / (F_HZ * ppw)
    return max(2, int(round(FACE_M / dx))), dx


def lobe_errors(lobe, ref) -> dict:
    """Errors against the continuous line (accuracy.py's measure, `lobe_db_*`) and, when `ref` is
    a pair, also against the discrete array of n point sources (`array_db_*`)."""
    import numpy as np

    def err(lobe, ref):
        ld = 20 * np.log10(np.abs(lobe) / np.abs(lobe).max())
        rd = 20 * np.log10(np.abs(ref) / np.abs(ref).max())
        main = rd > -20
        e = np.abs(ld - rd)[main]
        return float(e.max()), float(np.sqrt(np.mean(e**2)))

    cont, arr = ref if isinstance(ref, tuple) else (ref, None)
    out = dict(zip(("lobe_db_max_error", "lobe_db_rms_error"), err(lobe, cont)))
    if arr is not None:
        out.update(zip(("array_db_max_error", "array_db_rms_error"), err(lobe, arr)))
    return out


# --- role: reference (runs in .venv) ----------------------------------------------------------


def role_reference(spec: dict) -> dict:
    import numpy as np

    from difflattice.apps.accuracy import reference

    a = angles()
    out = {}
    for ppw in spec["ppw"]:
        n, dx = n_cells(ppw)
        key = ref_key(n, dx)
        if key not in out:
            from scipy.special import hankel1

            lobe, _ = reference(a, np.zeros(1), length_m=n * dx, range_m=RANGE_M)
            # the discrete array the solvers model: n isotropic point sources dx apart
            k = 2 * math.pi * F_HZ / C_M_S
            th = np.radians(a)
            yj = (np.arange(n) - (n - 1) / 2) * dx
            R = np.hypot(RANGE_M * np.cos(th)[:, None], RANGE_M * np.sin(th)[:, None] - yj[None, :])
            arr = (0.25j * hankel1(0, k * R)).sum(1)
            out[key] = {
                "length_m": n * dx,
                "n_cells": n,
                "re": lobe.real.tolist(),
                "im": lobe.imag.tolist(),
                "array_re": arr.real.tolist(),
                "array_im": arr.imag.tolist(),
            }
    return out


def load_ref(refs: dict, n: int, dx: float):
    """(continuous line of length n dx, discrete array of n point sources) complex lobes."""
    import numpy as np

    r = refs[ref_key(n, dx)]
    return np.asarray(r["re"]) + 1j * np.asarray(r["im"]), np.asarray(r["array_re"]) + 1j * np.asarray(r["array_im"])


# --- role: j-Wave (runs in .venv-jwave) -------------------------------------------------------


def nice_size(n: int) -> int:
    """Smallest m >= n with prime factors 2, 3, 5, 7 only (FFT-friendly)."""
    m = n
    while True:
        k = m
        for p in (2, 3, 5, 7):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += 1


def hankel01_asym(z):
    """(H_0^(1)(z), H_1^(1)(z)) by the same expansion, sharing the exponential."""
    import numpy as np

    e = np.sqrt(2 / (np.pi * z)) * np.exp(1j * (z - np.pi / 4))
    iz = 1j / z
    s0 = 1 + iz * (-1 / 8 + iz * (9 / 128 + iz * (-225 / 3072)))
    s1 = 1 + iz * (3 / 8 + iz * (-15 / 128 + iz * (315 / 3072)))
    return e * s0, -1j * e * s1


def contour_transform(P, box, k_cells, obs, up: int):
    """Kirchhoff-Helmholtz integral of the phasor field P (nx, ny) over the box [ix0, ix1] x
    [iy0, iy1] (cells), evaluated at obs (..., 2) in cells. p and grad p are the band-limited
    interpolants of P (spectral gradient, FFT resampling by `up`), trapezoid rule."""
    import numpy as np
    from scipy.signal import resample

    nx, ny = P.shape
    kx = 2 * np.pi * np.fft.fftfreq(nx)
    ky = 2 * np.pi * np.fft.fftfreq(ny)
    if nx % 2 == 0:
        kx[nx // 2] = 0.0
    if ny % 2 == 0:
        ky[ny // 2] = 0.0
    F = np.fft.fft2(P)
    gx = np.fft.ifft2(1j * kx[:, None] * F)
    gy = np.fft.ifft2(1j * ky[None, :] * F)

    def up2(a):
        return resample(resample(a, nx * up, axis=0), ny * up, axis=1) if up > 1 else a

    Pu, gxu, gyu = up2(P), up2(gx), up2(gy)
    ix0, ix1, iy0, iy1 = box
    pts, nrm, w, idx = [], [], [], []
    h = 1.0 / up
    xs = np.arange(ix0 * up, ix1 * up + 1)
    ys = np.arange(iy0 * up, iy1 * up + 1)
    for _side, (ii, jj, n) in {
        "left": (np.full_like(ys, ix0 * up), ys, (-1.0, 0.0)),
        "right": (np.full_like(ys, ix1 * up), ys, (1.0, 0.0)),
        "bottom": (xs, np.full_like(xs, iy0 * up), (0.0, -1.0)),
        "top": (xs, np.full_like(xs, iy1 * up), (0.0, 1.0)),
    }.items():
        ww = np.full(len(ii), h)
        ww[0] = ww[-1] = h / 2
        pts.append(np.stack([ii, jj], 1) / up)
        nrm.append(np.tile(n, (len(ii), 1)))
        w.append(ww)
        idx.append((ii, jj))
    pts, nrm, w = np.concatenate(pts), np.concatenate(nrm), np.concatenate(w)
    ii = np.concatenate([i for i, _ in idx])
    jj = np.concatenate([j for _, j in idx])
    p = Pu[ii, jj]
    dpdn = gxu[ii, jj] * nrm[:, 0] + gyu[ii, jj] * nrm[:, 1]
    shp = obs.shape[:-1]
    o = obs.reshape(-1, 2)
    out = np.empty(len(o), complex)
    for s in range(0, len(o), 4096):
        d = o[s : s + 4096, None, :] - pts[None]
        R = np.sqrt((d**2).sum(-1))
        dR_dn = -(d * nrm[None]).sum(-1) / R
        kR = k_cells * R
        H0, H1 = hankel01_asym(kR)
        G = 0.25j * H0
        dG_dR = -0.25j * k_cells * H1
        out[s : s + 4096] = (dG_dR * dR_dn) @ (p * w) - G @ (dpdn * w)
    return out.reshape(shp)


def jwave_case(
    ppw: float,
    mode: str,
    cfl: float,
    repeats: int,
    ref,
    pml: int = 20,
    gap: int | None = None,
    source: str = "gauss",
    sigma: float = 1.2,
    tail_periods: float = 6.0,
) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jwave.acoustics.time_varying import simulate_wave_propagation
    from jwave.geometry import Domain, Medium, Sources, TimeAxis

    n, dx = n_cells(ppw)
    n_src = n if mode == "line" else 1
    if gap is None:
        gap = 3 if source == "point" else int(math.ceil(5 * sigma))
    margin = gap + 4  # source to PML: contour gap + outer samples + slack
    nx = nice_size(2 * pml + 2 * margin + 1)
    ny = nice_size(2 * pml + 2 * margin + n_src)
    domain = Domain((nx, ny), (dx, dx))
    medium = Medium(domain=domain, sound_speed=C_M_S, density=1.2, pml_size=pml)
    dt = cfl * dx / C_M_S
    t_end = 4 / F_HZ + math.hypot(nx, ny) * dx / C_M_S + tail_periods / F_HZ
    time_axis = TimeAxis(dt=dt, t_end=t_end)
    nt = int(time_axis.Nt)
    t = np.arange(nt) * dt
    u = t * F_HZ / 4
    sig = np.where(u <= 1, (0.5 - 0.5 * np.cos(2 * np.pi * u)) * np.sin(2 * np.pi * F_HZ * t), 0.0).astype(np.float32)
    x0 = nx // 2
    y0 = ny // 2 - (n_src - 1) // 2
    pos = (tuple([x0] * n_src), tuple(range(y0, y0 + n_src)))
    if source == "point":
        signals = jnp.asarray(np.tile(sig, (n_src, 1)))
    else:  # one mask: a radially symmetric Gaussian (sigma cells) at each source cell, one signal
        X, Y = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
        mask = sum(np.exp(-((X - x0) ** 2 + (Y - y) ** 2) / (2 * sigma**2)) for y in pos[1])
        mask = jnp.asarray((mask / (2 * np.pi * sigma**2))[..., None].astype(np.float32))
        signals = jnp.asarray(sig)

    class MaskSource:  # what simulate_wave_propagation needs: on_grid(step) -> mass source field
        def __init__(self, signal):
            self.signal = signal

        def on_grid(self, step):
            return self.signal[step.astype(jnp.int32)] * mask

    kern = jnp.asarray(np.exp(1j * 2 * np.pi * F_HZ * t).astype(np.complex64))

    @jax.jit
    def run(signals):
        sources = (
            Sources(positions=pos, signals=signals, dt=dt, domain=domain) if source == "point" else MaskSource(signals)
        )
        field = simulate_wave_propagation(
            medium, time_axis, sources=sources, sensors=lambda p, u, rho: p.on_grid[..., 0]
        )
        return jnp.tensordot(kern, field.astype(jnp.complex64), axes=1)  # phasor at F_HZ, (nx, ny)

    t0 = time.perf_counter()
    P = np.asarray(jax.block_until_ready(run(signals)))
    first_s = time.perf_counter() - t0
    up = max(1, math.ceil(16 / ppw))
    th = np.radians(angles())
    r = RANGE_M / dx
    yc = y0 + (n_src - 1) / 2
    box = (x0 - gap, x0 + gap, y0 - gap, y0 + n_src - 1 + gap)
    k_cells = 2 * np.pi / ppw
    sims, posts = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        P = np.asarray(jax.block_until_ready(run(signals * 1.0)))
        t1 = time.perf_counter()
        if mode == "line":
            obs = np.stack([x0 + r * np.cos(th), yc + r * np.sin(th)], -1)
            lobe = contour_transform(P, box, k_cells, obs, up)
        else:
            offs = np.arange(n) - (n - 1) / 2
            obs = np.stack([x0 + r * np.cos(th), y0 + r * np.sin(th)], -1)
            pts = obs[:, None, :] - np.stack([np.zeros(n), offs], -1)[None]
            lobe = contour_transform(P, box, k_cells, pts, up).sum(1)
        t2 = time.perf_counter()
        sims.append(t1 - t0)
        posts.append(t2 - t1)
    sim_s, post_s = statistics.median(sims), statistics.median(posts)
    row = {
        "solver": "j-Wave",
        "setup": mode,
        "points_per_wavelength": ppw,
        "n_cells": n,
        "dx_m": dx,
        "grid": [nx, ny],
        "n_steps": nt,
        "cfl": cfl,
        "pml_points": pml,
        "contour_upsampling": up,
        "contour_gap_cells": gap,
        "source": source if source == "point" else f"gauss sigma={sigma} cells",
        "simulation_s": sim_s,
        "farfield_s": post_s,
        "wall_time_s": sim_s + post_s,
        "simulation_times_s": sims,
        "compile_s": max(0.0, first_s - sim_s),
        "first_call_s": first_s,
        **lobe_errors(lobe, ref),
    }
    log(json.dumps(row))
    return row


def role_jwave(spec: dict) -> dict:
    import jax
    import jaxlib

    refs = json.loads(Path(spec["ref"]).read_text())
    rows = []
    for ser in spec["series"]:
        for ppw in spec["ppw"]:
            n, dx = n_cells(ppw)
            try:
                row = jwave_case(ppw, ser["setup"], ser["cfl"], spec["repeats"], load_ref(refs, n, dx))
            except Exception as e:  # noqa: BLE001 (reported, not hidden)
                row = {
                    "solver": "j-Wave",
                    "setup": ser["setup"],
                    "cfl": ser["cfl"],
                    "points_per_wavelength": ppw,
                    "error": repr(e)[-800:],
                }
                log(row)
            rows.append({"series": ser["name"], **row})
    from importlib.metadata import version

    return {"versions": {"jwave": version("jwave"), "jax": jax.__version__, "jaxlib": jaxlib.__version__}, "rows": rows}


# --- role: difflattice (runs in .venv) --------------------------------------------------------


def role_difflattice(spec: dict) -> dict:
    import io
    from contextlib import redirect_stdout

    import jax
    import numpy as np

    from difflattice.apps import accuracy
    from difflattice.fit.transfer import free_field_transfer

    jax.config.update("jax_enable_x64", True)  # the float64 series (the library leaves precision to the caller)
    refs = json.loads(Path(spec["ref"]).read_text())
    with redirect_stdout(io.StringIO()):
        sweep = accuracy.sweep(
            cells_per_wavelength=tuple(spec["ppw"]), dtypes=tuple(spec["sweep_dtypes"]), repeats=spec["repeats"]
        )
    for r in sweep["rows"]:
        log(json.dumps(r))
    a = angles()
    lobe_only = []
    for dtype in spec["dtypes"]:
        for ppw in spec["lobe_only_ppw"]:
            n, dx = n_cells(ppw)
            ref = load_ref(refs, n, dx)
            times, sims = [], []
            for _ in range(spec["repeats"] + 1):  # the first run compiles
                t0 = time.perf_counter()
                T = free_field_transfer(
                    frequency_hz=F_HZ,
                    c_m_s=C_M_S,
                    n_cells=n,
                    cells_per_wavelength=ppw,
                    lobe_angle_deg=a,
                    lobe_range_m=RANGE_M,
                    dtype=dtype,
                    dispersion="continuum",
                )
                lobe = T.lobe @ np.ones(n)
                times.append(time.perf_counter() - t0)
                sims.append(T.info["simulation_s"])
            row = {
                "series": f"difflattice {dtype}",
                "solver": "difflattice",
                "setup": "cell (lobe only)",
                "points_per_wavelength": ppw,
                "dtype": dtype,
                "n_cells": n,
                "grid": T.info["grid_shape"],
                "n_steps": T.info["n_steps"],
                "wall_time_s": statistics.median(times[1:]),
                "simulation_s": statistics.median(sims[1:]),
                "compile_s": max(0.0, times[0] - statistics.median(times[1:])),
                **lobe_errors(lobe, ref),
            }
            lobe_only.append(row)
            log(json.dumps(row))
    from importlib.metadata import version

    return {
        "versions": {"difflattice": version("difflattice"), "jax": jax.__version__},
        "sweep": sweep,
        "lobe_only": lobe_only,
    }


# --- roles: throughput on one grid --------------------------------------------------------------

THROUGHPUT = {"nx": 840, "ny": 630, "steps": 200}


def role_throughput_jwave(spec: dict) -> dict:
    """j-Wave time steps on the kernel benchmark's 840x630 grid, float32, PML 20, one point
    source, one sensor point (so the record is not the cost): MLUPS, median of 3 after compiling."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jwave.acoustics.time_varying import simulate_wave_propagation
    from jwave.geometry import Domain, Medium, Sensors, Sources, TimeAxis

    nx, ny, steps = spec["nx"], spec["ny"], spec["steps"]
    dx = C_M_S / (F_HZ * 20)
    domain = Domain((nx, ny), (dx, dx))
    medium = Medium(domain=domain, sound_speed=C_M_S, density=1.2, pml_size=20)
    dt = spec["cfl"] * dx / C_M_S
    ta = TimeAxis(dt=dt, t_end=(steps - 0.5) * dt)
    nt = int(ta.Nt)
    t = np.arange(nt) * dt
    sig = jnp.asarray((np.sin(2 * np.pi * F_HZ * t) * (t < 5 / F_HZ)).astype(np.float32))[None]
    sensors = Sensors(positions=((nx // 2 + 20,), (ny // 2,)))

    @jax.jit
    def run(sig):
        src = Sources(positions=((nx // 2,), (ny // 2,)), signals=sig, dt=dt, domain=domain)
        return simulate_wave_propagation(medium, ta, sources=src, sensors=sensors)

    t0 = time.perf_counter()
    jax.block_until_ready(run(sig))
    first = time.perf_counter() - t0
    ts = []
    for _ in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(run(sig * 1.0))
        ts.append(time.perf_counter() - t0)
    t = statistics.median(ts)
    return {
        "solver": "j-Wave",
        "nx": nx,
        "ny": ny,
        "steps": nt,
        "cfl": spec["cfl"],
        "dtype": "float32",
        "time_s": t,
        "times_s": ts,
        "compile_s": max(0.0, first - t),
        "first_call_s": first,
        "mlups": nx * ny * nt / t / 1e6,
    }


def role_throughput_difflattice(spec: dict) -> dict:
    """The same grid with difflattice (public API): homogeneous air, PML edges (default Edges()),
    no sensors, the 104-cell line transducer of the kernel benchmark; forward run, float32."""
    import jax
    import jax.numpy as jnp

    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver import Stepper, run
    from difflattice.solver.sensors import Sensors
    from difflattice.solver.sources import ToneBurst, line_transducer

    nx, ny, steps = spec["nx"], spec["ny"], spec["steps"]
    g = make_grid(frequency_hz=F_HZ, cells_per_wavelength=20, c_max_m_s=C_M_S, shape=(nx, ny), dtype="float32")

    def make(w):
        src = line_transducer(g, (40 * g.dx_m, ny / 2 * g.dx_m), n_cells=104, signal=ToneBurst(F_HZ, 5), weights=w)
        return Stepper.build(g, Medium(C_M_S, 1.2), src, Sensors(), Edges())

    f = jax.jit(lambda w: run(make(w), steps).final.pressure)
    w0 = jnp.ones(104, g.jnp_dtype)
    t0 = time.perf_counter()
    jax.block_until_ready(f(w0))
    first = time.perf_counter() - t0
    ts = []
    for _ in range(3):
        t0 = time.perf_counter()
        jax.block_until_ready(f(w0 * 1.01))
        ts.append(time.perf_counter() - t0)
    t = statistics.median(ts)
    return {
        "solver": "difflattice",
        "case": "homogeneous air, PML edges, 104-cell line source, forward",
        "nx": nx,
        "ny": ny,
        "steps": steps,
        "dtype": "float32",
        "time_s": t,
        "times_s": ts,
        "compile_s": max(0.0, first - t),
        "first_call_s": first,
        "mlups": nx * ny * steps / t / 1e6,
    }


# --- driver -----------------------------------------------------------------------------------


def ensure_jwave_venv() -> Path:
    py = JW_VENV / "bin" / "python"
    if not py.exists():
        log(f"creating {JW_VENV} (pip install jwave)")
        subprocess.run([sys.executable, "-m", "venv", str(JW_VENV)], check=True)
        r = subprocess.run([str(JW_VENV / "bin" / "pip"), "install", "jwave"], capture_output=True, text=True)
        if r.returncode != 0:
            raise RuntimeError(f"pip install jwave failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
    return py


def call(py: Path, role: str, spec: dict, tmp: Path) -> dict:
    out = tmp / f"{role}.json"
    spec = {**spec, "out": str(out)}
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    log(f"--- {role} ({py})")
    t0 = time.perf_counter()
    r = subprocess.run(
        [str(py), str(Path(__file__).resolve()), "--role", role, "--spec", json.dumps(spec)],
        env=env,
        stdout=subprocess.PIPE,
        text=True,
    )
    if r.returncode != 0:
        raise RuntimeError(f"role {role} failed (exit {r.returncode}); stdout tail:\n{r.stdout[-2000:]}")
    res = json.loads(out.read_text())
    res["role_wall_s"] = time.perf_counter() - t0
    return res


def references(ppws, tmp: Path) -> Path:
    """Reference lobes, cached in out/ (they depend only on n dx)."""
    cache = ROOT / "out" / "jwave_compare_reference.json"
    have = json.loads(cache.read_text()) if cache.exists() else {}
    need = [p for p in ppws if ref_key(*n_cells(p)) not in have]
    if need:
        have.update(call(MAIN_PY, "reference", {"ppw": need}, tmp))
        have.pop("role_wall_s", None)
        cache.parent.mkdir(parents=True, exist_ok=True)
        cache.write_text(json.dumps(have))
    return cache


MEASURES = {"continuous line (accuracy.py)": "lobe_db_max_error", "discrete array (solver only)": "array_db_max_error"}
TIMES = {"total": "wall_time_s", "simulation only": "simulation_s"}


def coarsest(rows, key, thr):
    """The coarsest measured resolution whose error is at or below thr (resolution, not the noisy
    time, decides; errors are not always monotonic in the resolution)."""
    ok = [r for r in rows if "error" not in r and r.get(key) is not None and r[key] <= thr]
    return min(ok, key=lambda r: r["points_per_wavelength"]) if ok else None


def summarise(res: dict) -> dict:
    rows = [r for r in res.get("jwave", {}).get("rows", []) if "error" not in r] + res["difflattice"]["lobe_only"]
    series = list(dict.fromkeys(r["series"] for r in rows))
    out = {}
    for mname, key in MEASURES.items():
        for tname, tkey in TIMES.items():
            tab = []
            for thr in THRESHOLDS_DB:
                row = {"threshold_db": thr}
                for s in series:
                    c = coarsest([r for r in rows if r["series"] == s], key, thr)
                    row[s] = (
                        None
                        if c is None
                        else {
                            "time_s": c[tkey],
                            "points_per_wavelength": c["points_per_wavelength"],
                            "error_db": c[key],
                        }
                    )
                base = row.get("difflattice float32")
                for s in series:
                    if s.startswith("j-Wave") and row[s] and base:
                        row[f"ratio {s} / difflattice float32"] = row[s]["time_s"] / base["time_s"]
                tab.append(row)
            out[f"{mname}; {tname}"] = {"series": series, "rows": tab}
    tp = res.get("throughput")
    if tp and "j-Wave" in tp and "difflattice" in tp:
        out["projection"] = projection(res)
    return out


def projection(res: dict) -> list[dict]:
    """Not measured: cost of a direct full-domain simulation of a fixed physical region and time
    (no translation trick, the solver propagates to the far field), cost ~ (pts/wavelength)^3 /
    (Courant number x MLUPS), with the coarsest resolution meeting each threshold. j-Wave: its
    "line" series (its dispersion-free k-space scheme gives the same error at any range);
    difflattice: the "lattice" far-field rows of accuracy.sweep (the lattice's own dispersion
    over the 1 m range, i.e. what a direct simulation to 1 m gives)."""
    tp = res["throughput"]
    jw_rows = [r for r in res["jwave"]["rows"] if r.get("series") == "j-Wave line" and "error" not in r]
    dl_rows = [
        {**r, "points_per_wavelength": r["cells_per_wavelength"]}
        for r in res["difflattice"]["sweep"]["rows"]
        if r["dtype"] == "float32" and r["farfield_dispersion"] == "lattice"
    ]
    out = []
    for thr in THRESHOLDS_DB:
        j = coarsest(jw_rows, "lobe_db_max_error", thr)
        d = coarsest(dl_rows, "lobe_db_max_error", thr)
        row = {
            "threshold_db": thr,
            "jwave_ppw": j and j["points_per_wavelength"],
            "difflattice_ppw": d and d["points_per_wavelength"],
        }
        if j and d:
            cj = j["points_per_wavelength"] ** 3 / (tp["j-Wave"]["cfl"] * tp["j-Wave"]["mlups"])
            cd = d["points_per_wavelength"] ** 3 / ((1 / math.sqrt(2)) * tp["difflattice"]["mlups"])
            row["cost_ratio_jwave_over_difflattice"] = cj / cd
        out.append(row)
    return out


def fmt(x, spec=".3f"):
    return "" if x is None else format(x, spec)


def write_docs(res: dict) -> None:
    d = ROOT / "docs" / "benchmarks"
    d.mkdir(parents=True, exist_ok=True)
    (d / "jwave.json").write_text(json.dumps(res, indent=2) + "\n")
    L = [
        "# j-Wave against difflattice at equal lobe accuracy",
        "",
        f"{res['date_utc']}; {res['machine']}; {res['cpu_count']} CPUs; load average {res['load_average_start']} at the start, "
        f"{res['load_average_end']} at the end ({res['load_note']}).",
        "",
        f"Reproduce: `python3 {Path(__file__).relative_to(ROOT)}{' --quick' if res['quick'] else ''}` "
        "(creates `.venv-jwave` if missing; each side runs in its own venv and process, one after the other).",
        "",
    ]
    if res.get("reused_sweeps_from"):
        L += [
            f"The accuracy sweeps are from {res['reused_sweeps_from']}; the throughput part was run on "
            f"{res['throughput_date_utc']}.",
            "",
        ]
    if "jwave_error" in res:
        L += ["**j-Wave could not be run here:**", "", "```", res["jwave_error"], "```", ""]
    else:
        v = res["jwave"]["versions"]
        L += [
            f"Versions: jwave {v['jwave']} (jax {v['jax']}, jaxlib {v['jaxlib']}) in `.venv-jwave`; "
            f"difflattice {res['difflattice']['versions']['difflattice']} (jax {res['difflattice']['versions']['jax']}) in `.venv`.",
            "",
        ]
    if res.get("conclusion"):
        L += ["## Conclusion", "", res["conclusion"], ""]
    L += [
        "## Set-up",
        "",
        "Problem: `difflattice.apps.accuracy`'s case: a uniform line of n = round(35.7 mm / dx) cells one dx apart, 50 kHz, "
        "c = 343 m/s; lobe at 1 m, 0-60 deg in 0.05 deg steps, dB re its maximum. Error: max |dB| difference over the "
        "directions where the reference is above -20 dB (main lobe and first side lobes), against two references:",
        "",
        "- **continuous line** of length n dx (`difflattice.apps.accuracy.reference`, scipy Hankel quadrature): the measure "
        "of accuracy.py. It includes the error of replacing the face by n point cells (midpoint rule, "
        "≈ 0.11 dB × (6 / cells per λ)², the same for any solver that models the face as n cells);",
        "- **discrete array** of the same n isotropic point sources (exact 2-D Green's function, scipy): the solver's "
        "own error only.",
        "",
        "Series: **j-Wave line**: the whole line simulated with `jwave.acoustics.simulate_wave_propagation` "
        "(pseudo-spectral k-space, default PML of 20 points), Kirchhoff-Helmholtz transform from a box around it. "
        "**j-Wave cell**: one source simulated, its contour field translated over the n cell positions (difflattice's "
        "own fast path with the solver swapped). CFL 0.3 is `TimeAxis.from_medium`'s default; 0.6 shown as well (the "
        "k-space scheme is exact in time for a homogeneous medium, so the error does not change). **difflattice**: "
        "`free_field_transfer` (one cell + translation, continuum far field), lobe only; `accuracy.sweep`'s own rows "
        "(which also compute the wavefront block) are in the JSON and the last table.",
        "",
        f"Times: median of {res['repeats']} runs after a compiling run. *total*: j-Wave = jitted simulation (with the "
        "in-graph DFT at 50 kHz) + far-field transform (NumPy); difflattice = the whole `free_field_transfer` call "
        "(simulation + JAX far-field transform). *simulation only*: the time-stepping part.",
        "",
    ]
    for name, summ in res.get("equal_accuracy", {}).items():
        if name == "projection":
            continue
        series = summ["series"]
        L += [
            f"## Time to reach a lobe error: {name}",
            "",
            "Each cell: the median time at the coarsest measured resolution whose error is at or below the threshold "
            "(resolution in brackets). Ratio > 1: j-Wave slower.",
            "",
            "| max err ≤ (dB) | "
            + " | ".join(series)
            + " | "
            + " | ".join(f"{s} / difflattice f32" for s in series if s.startswith("j-Wave"))
            + " |",
            "|---" * (len(series) + sum(s.startswith("j-Wave") for s in series) + 1) + "|",
        ]
        for r in summ["rows"]:
            cells = [
                "not reached" if not r.get(s) else f"{r[s]['time_s']:.3f} s ({r[s]['points_per_wavelength']:g}/λ)"
                for s in series
            ]
            rat = [fmt(r.get(f"ratio {s} / difflattice float32"), ".2f") for s in series if s.startswith("j-Wave")]
            L.append(f"| {r['threshold_db']:g} | " + " | ".join(cells) + " | " + " | ".join(rat) + " |")
        L.append("")
    tp = res.get("throughput")
    if tp:
        tj, td = tp["j-Wave"], tp["difflattice"]
        L += [
            "## Throughput on one grid",
            "",
            f"{tj['nx']}x{tj['ny']} cells, float32, PML 20 cells, {td['steps']} steps, median of 3 after compiling, same session "
            f"(load average {tp['load_average']}): j-Wave {tj['mlups']:.1f} MLUPS (CFL {tj['cfl']}, first call incl. compile "
            f"{tj.get('first_call_s', float('nan')):.1f} s); difflattice {td['mlups']:.1f} MLUPS (homogeneous air, PML "
            f"edges, as the kernel benchmark's homogeneous+pml case; first call incl. compile {td.get('first_call_s', float('nan')):.1f} s). Per cell update j-Wave costs {td['mlups'] / tj['mlups']:.0f}x "
            "difflattice's (a k-space pseudo-spectral step is several FFTs over the whole grid; a lattice step is a local "
            "stencil).",
            "",
        ]
        proj = res.get("equal_accuracy", {}).get("projection")
        if proj:
            L += [
                "### Projection (not measured): a direct full-domain simulation",
                "",
                "Cost of simulating a fixed region and duration without the translation trick, so that the solver itself "
                "carries the wave to the far field: cost ∝ (points per wavelength)³ / (Courant number × MLUPS), at the "
                'coarsest resolution reaching each lobe error (accuracy.py\'s measure). j-Wave: its "line" rows (the '
                "k-space scheme has no numerical dispersion in a homogeneous medium, so its error does not grow with range); "
                "difflattice: accuracy.sweep's \"lattice\" far-field rows (the lattice's own dispersion over 1 m, i.e. "
                "what propagating 1 m on the lattice gives). Courant numbers: j-Wave 0.3 (its default), difflattice "
                "1/√2.",
                "",
                "| max err ≤ (dB) | j-Wave pts/λ | difflattice cells/λ | cost j-Wave / difflattice |",
                "|---|---|---|---|",
            ]
            for r in proj:
                c = r.get("cost_ratio_jwave_over_difflattice")
                L.append(
                    f"| {r['threshold_db']:g} | {r['jwave_ppw'] if r['jwave_ppw'] is not None else 'not reached'} | "
                    f"{r['difflattice_ppw'] if r['difflattice_ppw'] is not None else 'not reached in the sweep'} | "
                    f"{'' if c is None else f'{c:.3f}'} |"
                )
            L.append("")
    if "jwave" in res:
        L += [
            "## j-Wave runs",
            "",
            "| series | pts/λ | n | grid | steps | sim (s) | far field (s) | total (s) | compile (s) | "
            "err vs line (dB) | RMS | err vs array (dB) | RMS |",
            "|---" * 13 + "|",
        ]
        for r in res["jwave"]["rows"]:
            if "error" in r:
                L.append(f"| {r['series']} | {r['points_per_wavelength']:g} | error: {r['error'][:150]} |" + " |" * 10)
                continue
            L.append(
                f"| {r['series']} | {r['points_per_wavelength']:g} | {r['n_cells']} | {r['grid'][0]}x{r['grid'][1]} | {r['n_steps']} | "
                f"{r['simulation_s']:.3f} | {r['farfield_s']:.3f} | {r['wall_time_s']:.3f} | {r['compile_s']:.2f} | "
                f"{r['lobe_db_max_error']:.3f} | {r['lobe_db_rms_error']:.3f} | {r['array_db_max_error']:.4f} | {r['array_db_rms_error']:.4f} |"
            )
        L.append("")
    dl = res["difflattice"]
    L += [
        "## difflattice runs",
        "",
        "| run | dtype | cells/λ | n | grid | steps | sim (s) | total (s) | compile (s) | err vs line (dB) | RMS | "
        "err vs array (dB) | RMS |",
        "|---" * 13 + "|",
    ]
    for r in dl["lobe_only"]:
        L.append(
            f"| lobe only | {r['dtype']} | {r['points_per_wavelength']:g} | {r['n_cells']} | {r['grid'][0]}x{r['grid'][1]} | {r['n_steps']} | "
            f"{r['simulation_s']:.3f} | {r['wall_time_s']:.3f} | {r['compile_s']:.2f} | {r['lobe_db_max_error']:.3f} | "
            f"{r['lobe_db_rms_error']:.3f} | {r['array_db_max_error']:.4f} | {r['array_db_rms_error']:.4f} |"
        )
    for r in dl["sweep"]["rows"]:
        if r["farfield_dispersion"] == "continuum":
            L.append(
                f"| accuracy.sweep | {r['dtype']} | {r['cells_per_wavelength']:g} | {r['n_cells']} | | | {r['simulation_s']:.3f} | "
                f"{r['wall_time_s']:.3f} | | {r['lobe_db_max_error']:.3f} | | | |"
            )
    L.append("")
    if res.get("notes"):
        L += ["## Notes and differences from accuracy.py", ""] + [f"- {n}" for n in res["notes"]] + [""]
    (d / "jwave.md").write_text("\n".join(L))


def main():
    ap = argparse.ArgumentParser(description="j-Wave vs difflattice at equal lobe accuracy")
    ap.add_argument("--quick", action="store_true", help="fewer resolutions, one repeat")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-write", action="store_true", help="do not write docs/benchmarks/jwave.*")
    ap.add_argument(
        "--reuse",
        default=None,
        help="take the j-Wave and difflattice sweeps from this earlier jwave.json "
        "(re-runs only the throughput part and the summary)",
    )
    ap.add_argument("--no-throughput", action="store_true", help="skip the 840x630 throughput runs")
    ap.add_argument("--role", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--spec", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.role:
        spec = json.loads(args.spec)
        fn = {
            "reference": role_reference,
            "jwave": role_jwave,
            "difflattice": role_difflattice,
            "throughput_jwave": role_throughput_jwave,
            "throughput_difflattice": role_throughput_difflattice,
        }[args.role]
        Path(spec["out"]).write_text(json.dumps(fn(spec)))
        return
    jw_ppw = [2, 3, 4, 6] if args.quick else [2, 2.5, 3, 4, 5, 6, 8, 10]
    dl_ppw = [6, 8, 10] if args.quick else [6, 7, 8, 10, 12, 14, 20, 28, 40]
    series = [
        {"name": "j-Wave line", "setup": "line", "cfl": 0.3},
        {"name": "j-Wave cell", "setup": "cell", "cfl": 0.3},
        {"name": "j-Wave line CFL 0.6", "setup": "line", "cfl": 0.6},
    ]
    repeats = 1 if args.quick else args.repeats
    res = {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": f"{platform.machine()} {platform.processor()}".strip(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "quick": args.quick,
        "repeats": repeats,
        "load_average_start": [round(x, 2) for x in os.getloadavg()],
        "load_note": "the 2 CPU cores were shared with other agents' jobs during the run, so absolute times are noisy; "
        "both sides ran in the same session, one after the other",
    }
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        if args.reuse:
            old = json.loads(Path(args.reuse).read_text())
            keep = [
                "jwave",
                "jwave_error",
                "difflattice",
                "date_utc",
                "load_average_start",
                "load_average_end",
                "repeats",
                "quick",
            ]
            if args.no_throughput:  # keep the earlier throughput numbers too: only the summary is redone
                keep += ["throughput", "throughput_date_utc"]
            for k in keep:
                if k in old:
                    res[k] = old[k]
            res["reused_sweeps_from"] = old.get("reused_sweeps_from", f"the run of {old['date_utc']}")
            py = ensure_jwave_venv()
        else:
            ref = references(sorted(set(jw_ppw) | set(dl_ppw)), tmp)
            try:
                py = ensure_jwave_venv()
                res["jwave"] = call(
                    py, "jwave", {"ppw": jw_ppw, "series": series, "repeats": repeats, "ref": str(ref)}, tmp
                )
            except Exception as e:  # noqa: BLE001 (written into the report)
                res["jwave_error"] = str(e)
                log(res["jwave_error"])
            res["difflattice"] = call(
                MAIN_PY,
                "difflattice",
                {
                    "ppw": dl_ppw,
                    "lobe_only_ppw": [p for p in dl_ppw if p <= 20],
                    "sweep_dtypes": ["float32"],
                    "dtypes": ["float32", "float64"],
                    "repeats": repeats,
                    "ref": str(ref),
                },
                tmp,
            )
        partial = ROOT / "out" / "jwave_compare_partial.json"  # so a later failure does not lose the sweeps
        partial.parent.mkdir(parents=True, exist_ok=True)
        partial.write_text(json.dumps(res))
        if not args.no_throughput and "jwave" in res:
            res["throughput_date_utc"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
            steps = THROUGHPUT["steps"] // (4 if args.quick else 1)
            try:
                res["throughput"] = {
                    "j-Wave": call(py, "throughput_jwave", {**THROUGHPUT, "steps": steps, "cfl": 0.3}, tmp),
                    "difflattice": call(MAIN_PY, "throughput_difflattice", {**THROUGHPUT, "steps": steps}, tmp),
                    "load_average": [round(x, 2) for x in os.getloadavg()],
                }
            except Exception as e:  # noqa: BLE001 (reported in the JSON)
                res["throughput_error"] = str(e)[-1500:]
                log(res["throughput_error"])
            partial.write_text(json.dumps(res))
    if not args.reuse:
        res["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    res["equal_accuracy"] = summarise(res)
    res["notes"] = NOTES
    res["conclusion"] = conclusion(res)
    print(res["conclusion"])
    if not args.no_write:
        write_docs(res)


NOTES = [
    "Both sides get the lobe at 1 m from a Kirchhoff-Helmholtz transform over a contour around the source(s), with the "
    "continuum wavenumber; neither solver runs out to 1 m.",
    "difflattice's contour has p and dp/dn from two rings of cells (mean and difference). j-Wave's uses the "
    "band-limited (spectral) p and gradient of its own field, FFT-resampled to >= 16 samples per wavelength along the "
    "contour, trapezoid rule (in a dev check against the analytic field of the discrete array this transform alone "
    "agreed to 0.004 dB at 6 points per wavelength).",
    "j-Wave source: each source cell is a radially symmetric Gaussian mass source (sigma = 1.2 cells, unit integral; "
    "contour 6 cells away) instead of a single grid point. A grid-point source in a pseudo-spectral code is a "
    "sinc x sinc in space whose 1/r tails cross any contour, so the contour transform of point sources is wrong by "
    "up to ~0.4 dB (measured: 0.37 dB against the discrete array at 3 points per wavelength, line set-up). The "
    "Gaussian is isotropic, so it radiates the same pattern as a point source; its spectrum at the drive "
    "wavenumber only scales the field.",
    "j-Wave records the whole pressure field each step (its sensor API returns per-step values) and takes the 50 kHz "
    "DFT inside the same jitted function; difflattice accumulates phasors on the contour cells inside its scan.",
    "j-Wave: float32 (jax x64 off, its default); PML 20 points (its default size and profile); grid sizes rounded "
    "up to 2^a 3^b 5^c 7^d. In a dev check CFL 1.0 gave the same error as 0.3 (0.0040 vs 0.0041 dB against the "
    "array at 6 points per wavelength, 175 instead of 583 steps); not used for the tables.",
    "Same drive on both sides (4-cycle Hann tone burst, DFT at 50 kHz over the whole record); the lobe is normalised "
    "to its maximum, so the drive's spectrum cancels.",
    "2 points per wavelength is j-Wave's Nyquist limit: its row shows the failure, not a bug.",
    "The difflattice accuracy.sweep rows' times include the wavefront block at z = 16.5 mm (a larger grid); the "
    "lobe-only rows are the like-for-like times and are the ones in the equal-accuracy tables.",
]


def conclusion(res: dict) -> str:
    if "jwave" not in res:
        return "j-Wave could not be run here (see above)."
    ea = res["equal_accuracy"]
    parts = []
    for mname in MEASURES:
        bits = []
        for thr in (0.5, 0.2):
            tot = next(r for r in ea[f"{mname}; total"]["rows"] if r["threshold_db"] == thr)
            sim = next(r for r in ea[f"{mname}; simulation only"]["rows"] if r["threshold_db"] == thr)
            d, j = tot.get("difflattice float32"), tot.get("j-Wave line")
            if d and j:
                ds, js = sim["difflattice float32"], sim["j-Wave line"]
                bits.append(
                    f"≤ {thr:g} dB needs {j['points_per_wavelength']:g} pts/λ in j-Wave and {d['points_per_wavelength']:g} cells/λ "
                    f"in difflattice; total {j['time_s']:.2f} s vs {d['time_s']:.2f} s (j-Wave / difflattice "
                    f"{j['time_s'] / d['time_s']:.2f}), simulation only {js['time_s']:.3f} s vs {ds['time_s']:.3f} s "
                    f"({js['time_s'] / ds['time_s']:.1f})"
                )
            else:
                bits.append(
                    f"≤ {thr:g} dB: " + ("j-Wave not reached" if not j else "difflattice not reached in the sweep")
                )
        parts.append(f"- **Against the {mname}**: " + "; ".join(bits) + ".")
    parts.append(
        "- Both simulations here are tiny (difflattice: one cell on 54x59 cells at every resolution; j-Wave: the "
        "whole line on 63x70 to 63x112 points), so the times are mostly per-call overhead and the far-field "
        "transform rather than time stepping. j-Wave reaches a given lobe error at a coarser resolution, and its "
        "line set-up needs one contour transform where difflattice's translation path transforms per cell; "
        "difflattice's simulation part is the cheaper one (simulation-only ratios above)."
    )
    tp = res.get("throughput")
    if tp:
        parts.append(
            f"- Per cell update on a large grid (840x630, float32, same session), difflattice runs "
            f"{tp['difflattice']['mlups']:.0f} MLUPS and j-Wave {tp['j-Wave']['mlups']:.0f} MLUPS "
            f"({tp['difflattice']['mlups'] / tp['j-Wave']['mlups']:.1f}x)."
        )
        proj = ea.get("projection") or []
        pb = [
            f"≤ {r['threshold_db']:g} dB: j-Wave {r['jwave_ppw']:g} pts/λ vs difflattice "
            + (
                f"{r['difflattice_ppw']:g} cells/λ, j-Wave / difflattice cost {r['cost_ratio_jwave_over_difflattice']:.2f}"
                if r.get("cost_ratio_jwave_over_difflattice") is not None
                else "not reached up to 20 cells/λ"
            )
            for r in proj
            if r["threshold_db"] in (1.0, 0.5) and r["jwave_ppw"] is not None
        ]
        if pb:
            parts.append(
                "- Projection (not measured) for a direct full-domain simulation to 1 m, where difflattice's own "
                "dispersion counts: " + "; ".join(pb) + ". The translation + continuum far-field path is what "
                "keeps difflattice competitive on this problem."
            )
    parts.append(
        f"- Machine: {res['cpu_count']} CPU cores shared with other agents' jobs (load average "
        f"{res['load_average_start']} → {res['load_average_end']}); times are noisy at the 10-30 % level."
    )
    return "\n".join(parts)


if __name__ == "__main__":
    main()
