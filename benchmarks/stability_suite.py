"""Stability on stiff and extreme cases: each case states its expected behaviour and checks it.
Writes docs/stability.md and docs/stability.json.

    .venv/bin/python benchmarks/stability_suite.py      # ~3 minutes on 2 cores
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from difflattice.apps.validation import discrete_energy, plane_wave_rt  # noqa: E402
from difflattice.lattice import Edges  # noqa: E402
from difflattice.lattice.geometry import Box, Segment, rasterise  # noqa: E402
from difflattice.lattice.grid import MAX_COURANT, make_grid  # noqa: E402
from difflattice.lattice.medium import Medium  # noqa: E402
from difflattice.observe.analytic import discrete_rt  # noqa: E402
from difflattice.solver import Stepper, run, simulate  # noqa: E402
from difflattice.solver.sensors import Sensors  # noqa: E402
from difflattice.solver.sources import PointSources, ToneBurst  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ROWS = []


def case(name, expected):
    def deco(fn):
        t0 = time.perf_counter()
        try:
            ok, detail = fn()
        except Exception as e:  # a case that raises unexpectedly is a failure, recorded
            ok, detail = False, f"raised {type(e).__name__}: {str(e)[:160]}"
        ROWS.append(
            {
                "case": name,
                "expected": expected,
                "ok": bool(ok),
                "measured": detail,
                "seconds": time.perf_counter() - t0,
            }
        )
        print(("PASS " if ok else "FAIL ") + name + ": " + detail)
        return fn

    return deco


def _src(cell, w=1.0, dtype=jnp.float32, cycles=3, window="hann"):
    return PointSources(
        cells=[cell], signal=ToneBurst(50e3, cycles, window), weights=jnp.full(1, w, dtype), lags_s=jnp.zeros(1, dtype)
    )


def _peaks(grid, medium, src, steps, edges):
    r = simulate(grid, medium, src, Sensors(), n_steps=steps, edges=edges, throw=False)
    return np.asarray(r.peak_history)


@case("speed exactly 1/sqrt(2), 1e5 steps, closed box (f64)", "stable: energy conserved")
def _():
    g = make_grid(
        frequency_hz=50e3,
        cells_per_wavelength=12,
        c_max_m_s=343.0,
        shape=(32, 32),
        courant=MAX_COURANT,
        dtype="float64",
    )
    st = Stepper.build(g, Medium(343.0, 1.2), edges=Edges.all("rigid"))
    x, y = np.meshgrid(np.arange(32), np.arange(32), indexing="ij")
    p0 = jnp.asarray(np.exp(-((x - 10) ** 2 + (y - 12) ** 2) / 6.0))
    s0 = eqx.tree_at(lambda s: (s.p, s.p_prev), st.init(), (p0, p0))
    r = run(st, 100_000, state=s0, checkpoint=1000)
    e0, e1 = discrete_energy(st, p0, p0), discrete_energy(st, r.final.p, r.final.p_prev)
    return abs(e1 - e0) / e0 < 1e-9, f"relative energy drift {abs(e1 - e0) / e0:.1e}"


@case("speed 1.0001/sqrt(2)", "refused with a clear error")
def _():
    try:
        make_grid(
            frequency_hz=50e3, cells_per_wavelength=12, c_max_m_s=343.0, shape=(8, 8), courant=MAX_COURANT * 1.0001
        )
    except ValueError as e:
        return "stability limit" in str(e), f"ValueError: {str(e)[:90]}..."
    return False, "accepted"


for ratio in (1e-6, 1e-3, 1e3, 1e6):
    for model in ("conservative", "paper"):

        @case(
            f"impedance contrast rho2/rho1 = {ratio:g}, equal speeds, {model}", "R, T equal the exact discrete theory"
        )
        def _(ratio=ratio, model=model):
            R, T = plane_wave_rt(c1_m_s=343.0, c2_m_s=343.0, rho1=1.2, rho2=1.2 * ratio, model=model)
            g = make_grid(frequency_hz=50e3, cells_per_wavelength=20, c_max_m_s=343.0, shape=(3, 1))
            Rd, Td = discrete_rt(g.omega, g.courant, g.courant, 1.2, 1.2 * ratio, model)
            err = max(abs(R - Rd), abs(T - Td) / max(1, abs(Td)))
            return err < 1e-4 and np.isfinite(R), f"|R| = {abs(R):.6f}, error vs discrete theory {err:.1e}"


for cr in (0.1, 10.0):

    @case(
        f"speed contrast c2/c1 = {cr:g}, equal rho, conservative, 8+ cells/wavelength in both",
        "R, T equal the exact discrete theory",
    )
    def _(cr=cr):
        ppw1 = 20.0 if cr >= 1 else 80.0
        R, T = plane_wave_rt(
            c1_m_s=343.0, c2_m_s=343.0 * cr, rho1=1.2, rho2=1.2, model="conservative", cells_per_wavelength_1=ppw1
        )
        cmax = max(343.0, 343.0 * cr)
        g = make_grid(frequency_hz=50e3, cells_per_wavelength=ppw1 * cmax / 343.0, c_max_m_s=cmax, shape=(3, 1))
        Rd, Td = discrete_rt(
            g.omega, g.speed_to_lattice(343.0), g.speed_to_lattice(343.0 * cr), 1.2, 1.2, "conservative"
        )
        err = max(abs(R - Rd), abs(T - Td))
        return (
            err < 1e-4,
            f"|R| = {abs(R):.4f} (eq. 14: {abs((cr - 1) / (cr + 1)):.4f}), error vs discrete theory {err:.1e}",
        )


G = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(80, 80))


def _obstacle_case(shape, model="conservative", material="rigid", steps=5000, edges=Edges(thickness_cells=10)):
    occ = rasterise(shape, G, "hard")
    med = Medium(
        343.0,
        1.2,
        rigid=occ if material == "rigid" else None,
        soft=occ if material == "soft" else None,
        boundary_model=model,
    )
    pk = _peaks(G, med, _src((40, 40)), steps, edges)
    q = len(pk) // 4
    # an instability grows exponentially (orders of magnitude); the 2-D wake of the burst
    # fluctuates by less than 2x at late times
    ok = (
        float(occ.sum()) > 0
        and np.all(np.isfinite(pk))
        and pk[-q:].max() <= 2 * pk[-2 * q : -q].max()
        and pk[-q:].max() < 0.1 * pk.max()
    )
    return ok, f"{float(occ.sum()):.0f} obstacle cells; finite, late peak / max = {pk[-1] / pk.max():.1e}"


dx = G.dx_m
for model in ("conservative", "paper", "speed_zero"):

    @case(f"one-cell-thin rigid wall, {model}, 5000 steps", "stable, no late growth")
    def _(model=model):
        return _obstacle_case(Box(np.array([54.6 * dx, 10 * dx]), np.array([55.4 * dx, 70 * dx])), model)


@case("single-cell rigid obstacle, 5000 steps", "stable")
def _():
    return _obstacle_case(Box(np.array([49.6 * dx, 39.6 * dx]), np.array([50.4 * dx, 40.4 * dx])))


@case("wall touching the PML and the window edge, 5000 steps", "stable")
def _():
    return _obstacle_case(Segment(np.array([60 * dx, 0.0]), np.array([60 * dx, 30 * dx]), np.asarray(2 * dx)))


@case("sharp 90-degree corner (soft), 5000 steps", "stable")
def _():
    return _obstacle_case(Box(np.array([55 * dx, 45 * dx]), np.array([70 * dx, 70 * dx])), material="soft")


@case("PML corners, 20 000 steps, source near a corner", "stable, field decays")
def _():
    pk = _peaks(G, Medium(343.0, 1.2), _src((14, 14)), 20000, Edges(thickness_cells=10))
    return np.all(np.isfinite(pk)) and pk[-1] < 0.05 * pk.max(), f"final / max peak {pk[-1] / pk.max():.1e}"


@case("4 cells per wavelength, unwindowed 1-cycle burst (broadband), 10 000 steps", "stable (inaccurate, but bounded)")
def _():
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=4, c_max_m_s=343.0, shape=(60, 60))
    pk = _peaks(g, Medium(343.0, 1.2), _src((30, 30), cycles=1, window="rect"), 10000, Edges(thickness_cells=10))
    return np.all(np.isfinite(pk)), f"finite; final / max peak {pk[-1] / pk.max():.1e}"


for w in (1e-12, 1e12):

    @case(f"source weight {w:g} (float32)", "linear scaling, no loss beyond float32 round-off")
    def _(w=w):
        g64 = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(80, 80), dtype="float64")
        exact = _peaks(g64, Medium(343.0, 1.2), _src((40, 40), 1.0, jnp.float64), 400, Edges(thickness_cells=10))
        ref = _peaks(G, Medium(343.0, 1.2), _src((40, 40)), 400, Edges(thickness_cells=10))
        pk = _peaks(G, Medium(343.0, 1.2), _src((40, 40), w), 400, Edges(thickness_cells=10))
        dev = np.abs(pk / w - exact).max() / exact.max()
        base = np.abs(ref - exact).max() / exact.max()
        # the scaled float32 run must be as accurate as the unit-weight float32 run (round-off only)
        return np.all(
            np.isfinite(pk)
        ) and dev < 3 * base + 1e-7, f"deviation from float64 {dev:.1e} (unit weight, float32: {base:.1e})"


@case(
    "float32 denormals: weight 1e-38 vs 1 (late-time tiny fields)", "no slow-down (XLA CPU flushes denormals to zero)"
)
def _():
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(400, 400))
    times = {}
    for w in (1.0, 1e-38):
        st = Stepper.build(g, Medium(343.0, 1.2), _src((200, 200), w), Sensors(), Edges.all("rigid"))
        f = eqx.filter_jit(lambda s: run(s, 500).final.pressure)
        jax.block_until_ready(f(st))
        t0 = time.perf_counter()
        for _ in range(3):
            jax.block_until_ready(f(st))
        times[w] = (time.perf_counter() - t0) / 3
    ratio = times[1e-38] / times[1.0]
    return ratio < 1.5, f"time ratio tiny/normal = {ratio:.2f}"


@case("float32 vs float64 energy drift, closed heterogeneous box, 20 000 steps", "f32 drift small, f64 round-off")
def _():
    out = {}
    for dt in ("float32", "float64"):
        g = make_grid(frequency_hz=50e3, cells_per_wavelength=12, c_max_m_s=343.0, shape=(48, 48), dtype=dt)
        x, y = np.meshgrid(np.arange(48), np.arange(48), indexing="ij")
        blk = (x > 24) & (y > 16)
        med = Medium(
            jnp.asarray(np.where(blk, 200.0, 343.0), g.jnp_dtype), jnp.asarray(np.where(blk, 5.0, 1.2), g.jnp_dtype)
        )
        st = Stepper.build(g, med, edges=Edges.all("rigid"))
        p0 = jnp.asarray(np.exp(-((x - 12) ** 2 + (y - 12) ** 2) / 8.0), g.jnp_dtype)
        s0 = eqx.tree_at(lambda s: (s.p, s.p_prev), st.init(), (p0, p0))
        r = run(st, 20000, state=s0)
        e0, e1 = discrete_energy(st, p0, p0), discrete_energy(st, r.final.p, r.final.p_prev)
        out[dt] = abs(e1 - e0) / e0
    return out["float64"] < 1e-11 and out["float32"] < 1e-3, f"f32 {out['float32']:.1e}, f64 {out['float64']:.1e}"


@case("gradient through 10 000 steps (f64, checkpointed) vs central finite difference", "finite, agrees")
def _():
    g = make_grid(frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(40, 40), dtype="float64")

    def loss(w):
        src = PointSources(cells=[(20, 20)], signal=ToneBurst(50e3, 3), weights=w, lags_s=jnp.zeros(1))
        r = simulate(
            g,
            Medium(343.0, 1.2),
            src,
            Sensors(probes=[(25, 22)]),
            n_steps=10000,
            edges=Edges(thickness_cells=10),
            checkpoint="sqrt",
        )
        return jnp.sum(r.probes**2)

    w = jnp.ones(1) * 1.3
    gr = float(jax.grad(loss)(w)[0])
    h = 1e-4
    fd = float((loss(w + h) - loss(w - h)) / (2 * h))
    rel = abs(gr - fd) / abs(fd)
    return np.isfinite(gr) and rel < 1e-6, f"grad {gr:.6e}, FD {fd:.6e}, relative difference {rel:.1e}"


def main():
    ok = sum(r["ok"] for r in ROWS)
    (ROOT / "docs" / "stability.json").write_text(json.dumps(ROWS, indent=2))
    lines = [
        "# Stability on stiff and extreme cases",
        "",
        "Generated by `.venv/bin/python benchmarks/stability_suite.py`. Each case states what must happen and checks it;",
        "the fast ones are also tests (`tests/core/`). Fits that are ill-conditioned (mirror pairs, non-convergence,",
        "bad data) are covered by `tests/fit/test_fit_recovery.py`.",
        "",
        f"**{ok} of {len(ROWS)} cases behave as expected.**",
        "",
        "| case | expected | outcome | measured | s |",
        "|---|---|---|---|---|",
    ]
    for r in ROWS:
        lines.append(
            f"| {r['case']} | {r['expected']} | {'as expected' if r['ok'] else '**NOT as expected**'} | {r['measured']} | {r['seconds']:.1f} |"
        )
    lines += [
        "",
        "## Guaranteed and refused",
        "",
        "- Refused at construction: a lattice speed above 1/sqrt(2) cells/step; float64 without `jax_enable_x64`; sources in an absorbing layer; sensors outside the grid; bad scene/fit files (file, key, allowed values).",
        "- Detected at run time: a traced (fitted) speed above the limit; non-finite fields (`eqx.error_if`, with causes).",
        "- Guaranteed (tested): bounded fields at exactly the limit; energy conservation in closed boxes; no late growth for every edge type; linear scaling of the field with the source amplitude over 24 orders of magnitude.",
        "- Not detected: a medium resolved by fewer than ~2 cells per wavelength (e.g. a slow medium 10x slower than the fastest at 20 cells/λ) is beyond the lattice's cut-off: waves cannot enter it (total reflection). Keep every medium above ~8 cells per wavelength.",
        "",
    ]
    (ROOT / "docs" / "stability.md").write_text("\n".join(lines))
    print(f"{ok}/{len(ROWS)} as expected")


if __name__ == "__main__":
    main()
