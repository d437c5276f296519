"""`difflattice bench`: forward speed of the time loop in million lattice updates per second
(MLUPS), each case in its own process, implementations interleaved, medians of repeats, the load
average recorded.

Cases (float32): the bare homogeneous leapfrog (rigid window, one line source, no sensors) at
840 x 630 x 1000 steps and 2048 x 2048 x 200 steps, and a full-featured scene at 840 x 630 x 1000
(density and speed maps, a rigid obstacle, 20-cell PML, probes and phasors: the leapfrog on the
whole grid, the PML's split fields on the layer's cells only); the same two
840 x 630 scenes on the axisymmetric lattice (grid "840x630 rz": 840 cells along z, 630 rings, a
disc source); on a GPU also 4096 x 4096 x 200. Implementations: "native" (the C++ kernels, all
cores), "native-1thread", "jax" (the XLA loop); `reference=True` adds the numba (1 thread and all
cores; on the rz lattice numba's rz loops) and NumPy (2-D only) loops of
`benchmarks/reference_kernels.py` (their own virtual environment; numba is never a dependency of
difflattice), interleaved in the same run, and the ratios.

A run that starts with a 1-minute load average above `MAX_LOAD` is refused unless forced; a
forced run marks every line `"provisional": true`.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..lattice.kinds import LatticeKind

MAX_LOAD = 1.0
INNER_REPEATS = 3  # timed runs per process (after a compiling run); the process reports their median


@dataclass(frozen=True)
class Case:
    name: str  # "homogeneous" or "full"
    nx: int
    ny: int
    steps: int
    dtype: str = "float32"
    kind: str = "2d"  # "2d", "rz" (the axisymmetric lattice: nx along z, ny rings) or "3d"
    nz: int = 1  # cells along z of a 3-D case

    @property
    def cells(self) -> int:
        return self.nx * self.ny * self.nz

    @property
    def lattice(self) -> LatticeKind:
        from ..lattice.kinds import as_kind

        return as_kind(self.kind)

    @property
    def grid(self) -> str:
        if self.lattice.ndim == 3:
            return f"{self.nx}x{self.ny}x{self.nz}"
        return f"{self.nx}x{self.ny}" + (f" {self.kind}" if self.lattice.ring_metric else "")


CPU_CASES = (
    Case("homogeneous", 840, 630, 1000),
    Case("homogeneous", 2048, 2048, 200),
    Case("full", 840, 630, 1000),
    Case("homogeneous", 840, 630, 1000, kind="rz"),
    Case("full", 840, 630, 1000, kind="rz"),
)
# the 3-D leapfrog (issue 29): homogeneous air, rigid window, a 6 x 6 patch source; not in the
# default run (`python -m difflattice.apps.bench --cases 3d`, or `bench(cases=CPU_CASES_3D)`)
CPU_CASES_3D = (Case("homogeneous", 256, 256, 100, kind="3d", nz=256),)
GPU_CASES = (Case("homogeneous", 4096, 4096, 200),)
OWN_IMPLS = ("native", "native-1thread", "jax")
REFERENCE_IMPLS = ("numba-1thread", "numba", "numpy")


def reference_script() -> Path | None:
    """benchmarks/reference_kernels.py of a source checkout (None in an installed package)."""
    p = Path(__file__).resolve().parents[3] / "benchmarks" / "reference_kernels.py"
    return p if p.exists() else None


# ------------------------------------------------------------------------------------------
# one case in this process


def scene(case: Case):
    """(grid, medium, sources, sensors, edges) of a benchmark case."""
    import jax.numpy as jnp
    import numpy as np

    from ..lattice import Edges
    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from ..solver.sensors import Sensors
    from ..solver.sources import ToneBurst, disc_transducer, line_transducer

    if case.lattice.ndim == 3:
        return _scene_3d(case)
    nx, ny = case.nx, case.ny
    rz = case.lattice.ring_metric
    g = make_grid(
        frequency_hz=50e3,
        cells_per_wavelength=20,
        c_max_m_s=343.0,
        shape=(nx, ny),
        dtype=case.dtype,  # type: ignore[arg-type]
        kind=case.lattice,
    )
    if rz:  # a disc of 52 rings (the line's 104 cells as a diameter) facing +z
        src = disc_transducer(g, radius_m=52 * g.dx_m, z_m=40 * g.dx_m, signal=ToneBurst(50e3, 5), baffle="none")
    else:
        src = line_transducer(g, (40 * g.dx_m, ny / 2 * g.dx_m), n_cells=104, signal=ToneBurst(50e3, 5))
    if case.name == "homogeneous":
        return (
            g,
            Medium(343.0, 1.2),
            src,
            Sensors(),
            Edges.axisymmetric("rigid", "rigid", "rigid") if rz else Edges.all("rigid"),
        )
    dt = g.jnp_dtype
    x = jnp.arange(nx, dtype=dt)[:, None] * jnp.ones((1, ny), dt)
    rho = jnp.where(x > nx * 0.6, 2.0, 1.2).astype(dt)
    c = jnp.where(x > nx * 0.6, 300.0, 343.0).astype(dt)
    rigid = ((x > nx * 0.8) & (x < nx * 0.82)).astype(dt)
    probes = np.array([(nx // 2, ny // 2), (nx // 2 + 50, ny // 2)])
    arc = np.array([(nx // 2, j) for j in range(30, ny - 30, 10)])
    sens = Sensors(probes=probes, phasor_cells=arc)  # type: ignore[arg-type]
    return g, Medium(c, rho, rigid=rigid), src, sens, Edges.axisymmetric() if rz else Edges()


def _scene_3d(case: Case):
    """(grid, medium, sources, sensors, edges) of a 3-D case: the bare leapfrog (homogeneous)."""
    import jax.numpy as jnp
    import numpy as np

    from ..lattice import Edges
    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from ..solver.sensors import Sensors
    from ..solver.sources import PointSources, ToneBurst

    if case.name != "homogeneous":
        raise ValueError(f"3-D bench case {case.name!r}: only 'homogeneous' is defined")
    g = make_grid(
        frequency_hz=50e3,
        cells_per_wavelength=20,
        c_max_m_s=343.0,
        shape=(case.nx, case.ny, case.nz),
        dtype=case.dtype,  # type: ignore[arg-type]
        kind="3d",
    )
    j, k = np.meshgrid(np.arange(6) + case.ny // 2 - 3, np.arange(6) + case.nz // 2 - 3, indexing="ij")
    cells = np.stack([np.full(36, min(20, case.nx // 4)), j.ravel(), k.ravel()], axis=1)
    src = PointSources(cells, ToneBurst(50e3, 5), jnp.ones(36), jnp.zeros(36))
    return g, Medium(343.0, 1.2), src, Sensors(), Edges.all("rigid")


def time_run(stepper, steps: int, backend: str, repeats: int) -> tuple[float, list[float]]:
    """(first call's seconds, compile included; seconds of each of `repeats` timed runs) of
    `steps` steps of `stepper` in this process."""
    import jax

    from ..solver import run

    f = jax.jit(lambda s: run(s, steps, backend=backend).final.pressure)  # type: ignore[arg-type]
    t0 = time.perf_counter()
    jax.block_until_ready(f(stepper))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(stepper))
        times.append(time.perf_counter() - t0)
    return compile_s, times


def time_case(case: Case, impl: str, repeats: int = INNER_REPEATS) -> dict:
    """Compile, then time `repeats` runs of `case` with `impl` in this process."""
    import jax

    from ..solver import Stepper

    if impl == "native-1thread":
        os.environ["DIFFLATTICE_NATIVE_THREADS"] = "1"
    backend = "jax" if impl == "jax" else "native"
    stepper = Stepper.build(*scene(case))
    compile_s, times = time_run(stepper, case.steps, backend, repeats)
    t = statistics.median(times)
    return {
        "time_s": t,
        "times_s": times,
        "compile_s": compile_s,
        "device": jax.devices()[0].platform,
        "mlups": case.cells * case.steps / t / 1e6,
    }


# ------------------------------------------------------------------------------------------
# the interleaved run: one process per case and implementation


def _child(case: Case, impl: str) -> dict:
    load = os.getloadavg()[0]
    if impl in OWN_IMPLS:
        cmd = [sys.executable, "-m", "difflattice.apps.bench", "--child", json.dumps([case.__dict__, impl])]
    elif case.lattice.ndim == 3:  # benchmarks/reference_kernels_3d.py: an n^3 cube (its outer layer counted)
        script = reference_script()
        assert script is not None and case.nx == case.ny == case.nz
        cmd = [
            sys.executable,
            str(script.with_name("reference_kernels_3d.py")),
            "--kernel",
            "numba_serial" if impl == "numba-1thread" else "numba_parallel",
            "--n",
            str(case.nx),
            "--steps",
            str(case.steps),
            "--dtype",
            case.dtype,
            "--threads",
            str(1 if impl == "numba-1thread" else _cpus()),
        ]
    else:
        script = reference_script()
        kernel = {"numba-1thread": "numba_serial", "numba": "numba_parallel", "numpy": "numpy_inplace"}[impl]
        kernel += "_rz" if case.lattice.ring_metric else ""
        threads = 1 if impl == "numba-1thread" else _cpus()
        cmd = [
            sys.executable,
            str(script),
            "--kernel",
            kernel,
            "--size",
            f"{case.nx}x{case.ny}x{case.steps}",
            "--dtypes",
            case.dtype,
            "--threads",
            str(threads),
            "--repeats",
            str(INNER_REPEATS),
        ]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        return {"error": (r.stderr or r.stdout)[-500:], "load_avg": load}
    out = json.loads(r.stdout.strip().splitlines()[-1])
    if "rows" in out:  # reference_kernels.py
        row = out["rows"][0]
        out = {"time_s": row["time_s"], "times_s": row["times_s"], "mlups": row["mlups"], "device": "cpu"}
    out.setdefault("device", "cpu")
    out["load_avg"] = load
    return out


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def bench(
    *,
    reference: bool = False,
    rounds: int = 2,
    force: bool = False,
    quick: bool = False,
    cases=None,
    impls=None,
    emit=print,
) -> dict:
    """Run the benchmark; `emit` receives one JSON line per (case, implementation) and per ratio.
    `quick`: a tenth of the steps.
    Returns everything (machine, rows, ratios). Raises RuntimeError on a loaded machine unless
    `force`."""
    import jax

    load0 = os.getloadavg()[0]
    provisional = load0 > MAX_LOAD
    if provisional and not force:
        raise RuntimeError(
            f"1-minute load average {load0:.2f} > {MAX_LOAD}: the machine is busy and timings would "
            "not be comparable; wait for a quiet machine (`uptime` shows the load), or measure anyway "
            "with `difflattice bench --force` (every line then marked provisional: not a figure to quote)"
        )
    gpu = jax.default_backend() != "cpu"
    cases = list(cases or (GPU_CASES + CPU_CASES[:1] if gpu else CPU_CASES))
    if quick:  # a tenth of the steps (a check that everything runs, not a measurement)
        cases = [Case(c.name, c.nx, c.ny, max(1, c.steps // 10), c.dtype, c.kind, c.nz) for c in cases]
    impls = list(impls or (("jax",) if gpu else OWN_IMPLS))
    if reference and not gpu:
        if reference_script() is None:
            raise RuntimeError("--reference needs a source checkout of difflattice (benchmarks/reference_kernels.py)")
        impls += [i for i in REFERENCE_IMPLS if i not in impls]
    samples: dict[tuple, list[dict]] = {}
    for _ in range(rounds):  # interleaved: every implementation of a case, then the next case
        for case in cases:
            for impl in impls:
                if impl in REFERENCE_IMPLS and (
                    case.name != "homogeneous"
                    or (impl == "numpy" and (case.lattice.ring_metric or case.lattice.ndim == 3))
                ):
                    continue  # the reference loops: the bare homogeneous leapfrog (rz: numba only)
                samples.setdefault((case, impl), []).append(_child(case, impl))
    rows = []
    for (case, impl), runs in samples.items():
        ok = [r for r in runs if "mlups" in r]
        row = {
            "impl": impl,
            "case": case.name,
            "grid": case.grid,
            "steps": case.steps,
            "dtype": case.dtype,
            "mlups": statistics.median(r["mlups"] for r in ok) if ok else None,
            "mlups_per_round": [round(r["mlups"], 1) for r in ok],
            "load_avg": [round(r["load_avg"], 2) for r in runs],
            "threads": 1 if impl in ("native-1thread", "numba-1thread", "numpy") else _cpus(),
            "device": ok[0]["device"] if ok else None,
            "provisional": provisional,
        }
        if len(ok) < len(runs):
            row["error"] = next(r["error"] for r in runs if "error" in r)
        rows.append(row)
        emit(json.dumps(row))
    ratios = _ratios(rows)
    for r in ratios:
        emit(json.dumps(r))
    return {
        "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": platform.machine(),
        "processor": _processor(),
        "cpus": _cpus(),
        "jax": jax.__version__,
        "load_avg_at_start": load0,
        "load_avg_at_end": os.getloadavg()[0],
        "rounds": rounds,
        "inner_repeats": INNER_REPEATS,
        "provisional": provisional,
        "rows": rows,
        "ratios": ratios,
    }


def _ratios(rows) -> list[dict]:
    by = {(r["case"], r["grid"], r["impl"]): r["mlups"] for r in rows if r["mlups"]}
    out = []
    pairs = [
        ("native", "numba-1thread"),
        ("native-1thread", "numba-1thread"),
        ("native", "numba"),
        ("native", "jax"),
        ("native", "numpy"),
    ]
    for (case, grid, impl), v in by.items():
        for a, b in pairs:
            if impl == a and (case, grid, b) in by and case == "homogeneous":
                out.append(
                    {"ratio": f"{a}/{b}", "case": case, "grid": grid, "value": round(v / by[(case, grid, b)], 3)}
                )
        if case == "full" and ("homogeneous", grid, impl) in by:
            out.append(
                {
                    "ratio": f"full/homogeneous ({impl})",
                    "grid": grid,
                    "value": round(v / by[("homogeneous", grid, impl)], 3),
                }
            )
    return out


def _processor() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def markdown(result: dict) -> str:
    """The benchmark as a Markdown table (docs/performance.md)."""
    lines = [
        f"{result['date_utc']}, {result['processor']} ({result['cpus']} CPUs), JAX {result['jax']}; "
        f"load average {result['load_avg_at_start']:.2f} at the start, {result['load_avg_at_end']:.2f} at the end"
        + (" (**provisional**: the machine was not quiet)" if result["provisional"] else "")
        + ".",
        "",
        "| case | grid x steps | impl | threads | MLUPS (median) | per round | load avg |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        m = "error" if r["mlups"] is None else f"{r['mlups']:.0f}"
        lines.append(
            f"| {r['case']} | {r['grid']} x {r['steps']} | {r['impl']} | {r['threads']} | {m} | "
            f"{', '.join(f'{x:.0f}' for x in r['mlups_per_round'])} | {', '.join(map(str, r['load_avg']))} |"
        )
    if result["ratios"]:
        lines += ["", "| ratio | grid | value |", "|---|---|---|"]
        lines += [f"| {r['ratio']} | {r['grid']} | {r['value']:.2f} |" for r in result["ratios"]]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    """The child process: `python -m difflattice.apps.bench --child '[case, impl]'`; or a run of the
    3-D case (not in `difflattice bench`'s default set): `python -m difflattice.apps.bench --cases 3d
    [--reference] [--rounds N] [--force] [--quick] [--out DIR]`."""
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--child", default=None)
    ap.add_argument("--cases", choices=("3d",), default=None)
    ap.add_argument("--reference", action="store_true")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--force", action="store_true")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.child:
        case_kw, impl = json.loads(args.child)
        print(json.dumps(time_case(Case(**case_kw), impl)))
        return 0
    if args.cases is None:
        ap.error("give --child (internal) or --cases 3d (use `difflattice bench` for the default cases)")
    result = bench(reference=args.reference, rounds=args.rounds, force=args.force, quick=args.quick, cases=CPU_CASES_3D)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "bench3d.json").write_text(json.dumps(result, indent=2) + "\n")
        (args.out / "bench3d.md").write_text(markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
