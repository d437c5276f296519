"""Work against precision of the three 3-D stencils (standard 7-point, isotropic 19-point, wide
25-point): the same scene in metres (a closed box of air, `--size-m` on a side, a pulse from a
corner, run for the time sound takes to cross it) at 4-8 cells/wavelength, each run timed as the
median of `--repeats` interleaved repeats (every scheme and resolution once per round, so the
ratios come from one run on the same loaded machine), beside each scheme's worst phase-speed
error over the axes and the face and body diagonals, measured from simulated arrivals
(`difflattice accuracy --case dispersion3d --out DIR` with `--accuracy DIR`; the dispersion
relation's where absent).

    PYTHONPATH=$PWD/src python benchmarks/wide3d_work_precision.py --accuracy DIR --out docs/benchmarks
writes docs/benchmarks/wide3d_work_precision.{json,md}."""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from pathlib import Path

import numpy as np

SCHEMES = {"standard": 0.577, "isotropic": 0.86, "wide": 0.595}
CPW = (4.0, 5.0, 6.0, 7.0, 8.0)
F_HZ, C_M_S = 40e3, 343.0


def _stepper(scheme: str, cpw: float, size_m: float):
    import jax.numpy as jnp

    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver import Stepper
    from difflattice.solver.sources import PointSources, ToneBurst

    dx = C_M_S / F_HZ / cpw
    n = int(round(size_m / dx))
    grid = make_grid(
        frequency_hz=F_HZ,
        cells_per_wavelength=cpw,
        c_max_m_s=C_M_S,
        shape=(n, n, n),
        courant=SCHEMES[scheme],
        dtype="float32",
        kind="3d",
        stencil=scheme,
    )
    src = PointSources(
        cells=np.array([[n // 4] * 3]), signal=ToneBurst(F_HZ, 2), weights=jnp.ones(1), lags_s=jnp.zeros(1)
    )
    stepper = Stepper.build(grid, Medium(C_M_S, 1.2), src, edges=Edges.all("rigid"))
    steps = int(math.ceil(n / SCHEMES[scheme]))  # the time sound takes to cross the box
    return stepper, steps, n


def _loop(stepper, steps: int):
    """The compiled leapfrog over `steps` steps (the stepper's own step, no records): compiled
    once here, so that a timing is the stepping alone (`solver.run` also builds its records)."""
    import equinox as eqx
    import jax

    @eqx.filter_jit
    def go(stepper, state):
        return jax.lax.fori_loop(0, steps, lambda _, s: stepper.step(s)[0], state)

    state = stepper.init()
    jax.block_until_ready(go(stepper, state).p)  # compile
    return lambda: go(stepper, state)


def _timed(loop) -> float:
    import jax

    t0 = time.perf_counter()
    jax.block_until_ready(loop().p)
    return time.perf_counter() - t0


def _errors(acc_dir: str | None) -> dict:
    """worst |phase-speed error| per (scheme, cpw): measured rows where given, else the formula."""
    from difflattice.observe.analytic3d import phase_velocity_3d

    out: dict = {}
    if acc_dir:
        doc = json.loads((Path(acc_dir) / "accuracy_dispersion3d.json").read_text())
        for r in doc["rows"]:
            key = (r["scheme"], float(r["cells_per_wavelength"]))
            out[key] = max(out.get(key, 0.0), abs(r["phase_speed_error"]))
    for s, c in SCHEMES.items():
        for cpw in CPW:
            if (s, cpw) not in out:
                om = 2 * math.pi * c / cpw
                out[(s, cpw, "formula")] = max(
                    abs(float(phase_velocity_3d(om, c, d, stencil=s)) / c - 1)
                    for d in ((1, 0, 0), (1, 1, 0), (1, 1, 1))
                )
    return out


def per_update(n: int, repeats: int) -> dict:
    """MLUPS of each stencil on an n^3 box (rigid sides, float32, 20 compiled steps), in air and
    around a rigid post (the isotropic links, the wide rows), interleaved, median of `repeats`."""
    import jax.numpy as jnp

    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver import Stepper

    x, y, _ = np.meshgrid(*[np.arange(n)] * 3, indexing="ij")
    post = jnp.asarray((((x - n // 2) ** 2 + (y - n // 2) ** 2) < 25).astype(np.float32))
    loops = {}
    for case in ("air", "post"):
        for s, c in SCHEMES.items():
            g = make_grid(
                frequency_hz=F_HZ,
                cells_per_wavelength=6,
                c_max_m_s=C_M_S,
                shape=(n, n, n),
                courant=c,
                dtype="float32",
                kind="3d",
                stencil=s,
            )
            med = Medium(C_M_S, 1.2) if case == "air" else Medium(C_M_S, 1.2, rigid=post)
            loops[(case, s)] = _loop(Stepper.build(g, med, edges=Edges.all("rigid")), 20)
    times: dict = {k: [] for k in loops}
    for _ in range(repeats):
        for k, loop in loops.items():
            times[k].append(_timed(loop))
    return {f"{c}/{s}": n**3 * 20 / statistics.median(v) / 1e6 for (c, s), v in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size-m", type=float, default=0.09)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--accuracy", default=None, help="DIR of accuracy_dispersion3d.json (measured errors)")
    ap.add_argument("--out", default="docs/benchmarks")
    ap.add_argument("--per-update", type=int, default=80, help="n of the n^3 box of the MLUPS comparison (0: skip)")
    a = ap.parse_args()
    steppers = {(s, cpw): _stepper(s, cpw, a.size_m) for s in SCHEMES for cpw in CPW}
    loops = {k: _loop(st, steps) for k, (st, steps, _) in steppers.items()}
    times: dict = {k: [] for k in steppers}
    load0 = os.getloadavg()[0]
    for rnd in range(a.repeats):
        for k, loop in loops.items():
            times[k].append(_timed(loop))
        print(f"round {rnd + 1}/{a.repeats} done", flush=True)
    load1 = os.getloadavg()[0]
    mlups = per_update(a.per_update, a.repeats) if a.per_update else {}
    errs = _errors(a.accuracy)
    base = statistics.median(times[("isotropic", 6.0)])
    rows = []
    for (s, cpw), (_, steps, n) in steppers.items():
        med = statistics.median(times[(s, cpw)])
        err = errs.get((s, cpw))
        src = "measured"
        if err is None:
            err, src = errs[(s, cpw, "formula")], "formula"
        rows.append(
            dict(
                scheme=s,
                cells_per_wavelength=cpw,
                courant=SCHEMES[s],
                cells=n**3,
                steps=steps,
                seconds_median=med,
                seconds_all=times[(s, cpw)],
                time_vs_isotropic_6cpw=med / base,
                worst_phase_speed_error=err,
                error_source=src,
            )
        )
        print(
            f"{s:9s} cpw {cpw:3.0f} {n}^3 x {steps} steps: {med:.3f} s ({med / base:.2f}x iso@6) worst error {100 * err:.3f} % ({src})"
        )
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = dict(
        size_m=a.size_m,
        frequency_hz=F_HZ,
        repeats=a.repeats,
        dtype="float32",
        backend="jax (XLA CPU)",
        load_average_start=load0,
        load_average_end=load1,
        cores=os.cpu_count(),
        when=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        per_update_n=a.per_update,
        note="machine shared with other agents: absolute seconds are not valid figures; the ratios are from one interleaved run",
    )
    (out / "wide3d_work_precision.json").write_text(
        json.dumps(dict(meta=meta, rows=rows, mlups=mlups), indent=1) + "\n"
    )
    (out / "wide3d_work_precision.md").write_text(markdown(meta, rows, mlups))


def markdown(meta: dict, rows: list, mlups: dict) -> str:
    """The markdown table of a run (`main`'s JSON fields)."""
    lines = [
        "# 3-D stencils: work against precision (issue 29)",
        "",
        f"A closed box of air {meta['size_m'] * 100:g} cm on a side at {meta['frequency_hz'] / 1e3:g} kHz, run for the time sound takes to cross it "
        f"(float32, the compiled JAX/XLA CPU leapfrog, compile excluded); each time the median of {meta['repeats']} interleaved rounds; {meta['when']}, "
        f"{meta['cores']} cores **shared with other agents** (load average {meta['load_average_start']:.2f} at start, {meta['load_average_end']:.2f} at end): the "
        "seconds are not valid speed figures, the ratios (all from this one run) are what to read. Worst error: the largest "
        "|phase-speed error| over axis, face and body diagonal, measured from simulated arrivals "
        "(`difflattice accuracy --case dispersion3d`).",
        "",
        "| scheme (courant) | cells/λ | cells | steps | time (s) | time / isotropic at 6 | worst phase-speed error |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in sorted(rows, key=lambda r: (r["scheme"], r["cells_per_wavelength"])):
        lines.append(
            f"| {r['scheme']} ({r['courant']}) | {r['cells_per_wavelength']:g} | {r['cells']} | {r['steps']} | "
            f"{r['seconds_median']:.3f} | {r['time_vs_isotropic_6cpw']:.2f} | {100 * r['worst_phase_speed_error']:.2f} % "
            f"{'' if r['error_source'] == 'measured' else '(formula)'}|"
        )
    if mlups:
        n = meta.get("per_update_n", 80)
        lines += [
            "",
            f"Cost per cell update: {n}^3 cells, rigid sides, 20 steps, in air and around a rigid post (radius 5 cells), "
            f"interleaved, median of {meta['repeats']}, same run (MLUPS, higher is faster; read the ratios):",
            "",
            "| case | standard | isotropic | wide | wide / isotropic time per update |",
            "|---|---:|---:|---:|---:|",
        ]
        for c in ("air", "post"):
            m = {s: mlups[f"{c}/{s}"] for s in SCHEMES}
            lines.append(
                f"| {c} | {m['standard']:.0f} | {m['isotropic']:.0f} | {m['wide']:.0f} | {m['isotropic'] / m['wide']:.2f} |"
            )
    lines += [
        "",
        "Reproduce: `PYTHONPATH=$PWD/src python benchmarks/wide3d_work_precision.py --accuracy DIR` "
        "after `difflattice accuracy --case dispersion3d --cells-per-wavelength 4 5 6 7 8 --out DIR`.",
    ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
