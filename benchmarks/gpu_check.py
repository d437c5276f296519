"""One-command GPU check (`benchmarks/gpu_check.sh`): throughput of the lattice step on the
accelerator against its memory-bandwidth bound, and the accelerator's numbers against the CPU's.

    python benchmarks/gpu_check.py [--quick] [--json OUT.json]

Cases (float32, JAX path, rigid window sides, homogeneous air: the two-field leapfrog):

- 2-D 4096^2 (5-point), 3-D 512^3 (7-point), 3-D 512^3 isotropic (19-point) and 3-D 512^3 wide
  (25-point, the 3-D default);
- MLUPS = cells x steps / time (after a compiling run; the median of 3 timed runs);
- the bound: the leapfrog must read P(n), P(n-1) and write P(n+1) once per update, 12 bytes in
  float32, so MLUPS <= bandwidth / 12 B; "fraction" = MLUPS / that bound, with the bandwidth both
  as measured here (a device-to-device copy, 2 x bytes / time) and as the card's data sheet
  figure where the device kind is known;
- check: a small 2-D, 3-D, 3-D isotropic and 3-D wide scene (a tone burst from a point, cut-cell sphere
  or disc, probes) on the accelerator and on the CPU (`jax.devices("cpu")`), probes agreeing to
  1e-4 of their scale (float32 rounding over a few hundred steps).

Prints one line per figure and a verdict; exit 1 if a check fails. Keep it under 8 minutes:
`--quick` halves the big grids (2048^2, 256^3).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

DATASHEET_TB_S = {  # HBM bandwidth by device-kind substring (vendor data sheets)
    "H200": 4.8,
    "H100 SXM": 3.35,
    "H100 80GB HBM3": 3.35,
    "H100 PCIe": 2.0,
    "H100": 3.35,
    "A100-SXM4-80GB": 2.04,
    "A100": 1.56,
    "L40S": 0.864,
    "V100": 0.9,
}


def _datasheet(kind: str) -> float | None:
    for key, tb in DATASHEET_TB_S.items():
        if key.lower() in kind.lower():
            return tb
    return None


def copy_bandwidth_tb_s(device, n_bytes: int = 2 << 30, reps: int = 10) -> float:
    """Device-to-device copy bandwidth (read + write), TB/s: the median of 5 timings of `reps`
    copies dispatched back to back (one copy of 2 GiB takes ~1 ms on an H200, so a single timed
    call also counts its dispatch and synchronisation: session 17's single copies read 3.06 TB/s
    there, below the 2-D stencil's own traffic)."""
    x = jax.device_put(jnp.ones(n_bytes // 4, jnp.float32), device)
    f = jax.jit(lambda a: a * 1.0000001)
    f(x).block_until_ready()
    times = []
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(reps):
            y = f(x)
        y.block_until_ready()
        times.append((time.perf_counter() - t) / reps)
    return 2 * n_bytes / statistics.median(times) / 1e12


def _courant(kind: str, stencil: str) -> float:
    from difflattice.lattice.kinds import DEFAULT_COURANT_3D_WIDE

    if kind == "2d":
        return 0.7
    return {"isotropic": 0.86, "wide": DEFAULT_COURANT_3D_WIDE}.get(stencil, 0.57)


def _stepper(shape, stencil="standard"):
    from difflattice.lattice import Edges, Medium
    from difflattice.lattice.grid import make_grid
    from difflattice.solver import Stepper

    kind = "3d" if len(shape) == 3 else "2d"
    courant = _courant(kind, stencil)
    g = make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=10,
        c_max_m_s=343.0,
        shape=shape,
        courant=courant,
        kind=kind,
        stencil=stencil,
    )
    return Stepper.build(g, Medium(343.0, 1.2), edges=Edges.all("rigid"))


def mlups(shape, n_steps: int, stencil="standard", device=None) -> float:
    """MLUPS of the JAX leapfrog on `device`: the median of 3 timed runs after a compiling one."""
    from difflattice.solver.scan import run_jax

    with jax.default_device(device):
        st = _stepper(shape, stencil)
        p0 = jnp.zeros(shape, jnp.float32).at[tuple(n // 2 for n in shape)].set(1.0)
        state = eqx_set(st.init(), p0)
        f = jax.jit(lambda s, x: run_jax(s, n_steps, state=x).final.pressure)
        jax.block_until_ready(f(st, state))
        times = []
        for _ in range(3):
            t = time.perf_counter()
            jax.block_until_ready(f(st, state))
            times.append(time.perf_counter() - t)
    return math.prod(shape) * n_steps / statistics.median(times) / 1e6


def eqx_set(state, p0):
    import equinox as eqx

    return eqx.tree_at(lambda s: (s.p, s.p_prev), state, (p0, p0))


CHECK = {
    "2d": ((96, 80), "standard", 300),
    "3d": ((40, 36, 32), "standard", 150),
    "3d isotropic": ((40, 36, 32), "isotropic", 150),
    "3d wide": ((40, 36, 32), "wide", 150),
}


def probes_on(device, shape, stencil, n_steps) -> np.ndarray:
    """Probe series of a small scene with a cut-cell obstacle, run on `device`."""
    from difflattice.lattice import Edges, Medium
    from difflattice.lattice.grid import make_grid
    from difflattice.solver import Sensors, ToneBurst, simulate
    from difflattice.solver.sources import PointSources

    with jax.default_device(device):
        kind = "3d" if len(shape) == 3 else "2d"
        courant = _courant(kind, stencil)
        g = make_grid(
            frequency_hz=40e3,
            cells_per_wavelength=8,
            c_max_m_s=343.0,
            shape=shape,
            courant=courant,
            kind=kind,
            stencil=stencil,
        )
        idx = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1).astype(float)
        centre = np.array(shape) * 0.65
        rigid = np.clip(4.5 - np.linalg.norm(idx - centre, axis=-1), 0.0, 1.0)
        if stencil in ("isotropic", "wide"):
            rigid = (rigid > 0.5).astype(float)  # hard cells: within the measured-spectrum bound
        src_cell = tuple(int(n * 0.3) for n in shape)
        src = PointSources(
            cells=np.array([src_cell]), signal=ToneBurst(40e3, 2), weights=jnp.ones(1), lags_s=jnp.zeros(1)
        )
        probes = np.array([[int(n * 0.5) for n in shape], [int(n * 0.8) for n in shape], [int(n * 0.2) for n in shape]])
        res = simulate(
            g,
            Medium(343.0, 1.2, rigid=jnp.asarray(rigid, jnp.float32)),
            src,
            Sensors(probes=probes),
            n_steps=n_steps,
            edges=Edges.all("pml", thickness_cells=6),
            preflight="off",
            backend="jax",
        )
        return np.asarray(res.probes)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2048^2 and 256^3 instead of 4096^2 and 512^3")
    ap.add_argument("--json", default=None, help="write the figures to this file")
    ap.add_argument("--n2", type=int, default=None, help="2-D grid side (a smoke test on a CPU: e.g. 256)")
    ap.add_argument("--n3", type=int, default=None, help="3-D grid side (a smoke test on a CPU: e.g. 48)")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    dev = jax.devices()[0]
    cpu = jax.devices("cpu")[0]
    kind = getattr(dev, "device_kind", dev.platform)
    print(f"device: {dev.platform} {kind} ({len(jax.devices())} visible); jax {jax.__version__}", flush=True)
    bw = copy_bandwidth_tb_s(dev)
    sheet = _datasheet(kind)
    print(f"copy bandwidth (measured): {bw:.2f} TB/s; data sheet: {sheet if sheet else 'unknown'} TB/s", flush=True)
    n2, n3 = (2048, 256) if args.quick else (4096, 512)
    n2, n3 = args.n2 or n2, args.n3 or n3
    out: dict = {"device": f"{dev.platform} {kind}", "copy_tb_s": bw, "datasheet_tb_s": sheet, "cases": {}}
    for name, shape, stencil, steps in (
        (f"2d {n2}^2 5-point", (n2, n2), "standard", 200),
        (f"3d {n3}^3 7-point", (n3,) * 3, "standard", 50),
        (f"3d {n3}^3 19-point isotropic", (n3,) * 3, "isotropic", 50),
        (f"3d {n3}^3 25-point wide (default)", (n3,) * 3, "wide", 50),
    ):
        m = mlups(shape, steps, stencil, dev)
        bound = bw * 1e12 / 12 / 1e6
        row = {"mlups": m, "fraction_of_copy_bound": m / bound}
        line = f"{name}: {m:,.0f} MLUPS = {m / bound:.2f} of the measured-bandwidth bound ({bound:,.0f})"
        if sheet:
            sb = sheet * 1e12 / 12 / 1e6
            row["fraction_of_datasheet_bound"] = m / sb
            line += f", {m / sb:.2f} of the data-sheet bound ({sb:,.0f})"
        print(line, flush=True)
        out["cases"][name] = row
    ok = True
    for name, (shape, stencil, steps) in CHECK.items():
        a = probes_on(dev, shape, stencil, steps)
        b = probes_on(cpu, shape, stencil, steps)
        scale = float(np.abs(b).max())
        err = float(np.abs(a - b).max()) / scale
        good = scale > 0 and err < 1e-4
        ok &= good
        print(
            f"check {name} {shape}, {steps} steps: accelerator vs CPU max |diff| / scale = {err:.2e} "
            f"({'ok' if good else 'FAIL'})",
            flush=True,
        )
        out["cases"][f"check {name}"] = {"relative_difference": err, "ok": good}
    out["seconds"] = time.perf_counter() - t_start
    print(f"{'all checks passed' if ok else 'CHECK FAILED'} in {out['seconds']:.0f} s", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
