"""PML scenes' outputs of two versions of the solver, compared: run it with one checkout on
PYTHONPATH to write, with the other to compare (the layered PML state against the split fields on
every cell, or any later change of the PML step).

    PYTHONPATH=/path/to/old/src python benchmarks/pml_versions.py --write old.npz
    PYTHONPATH=src python benchmarks/pml_versions.py --compare old.npz

Scenes (97 steps, float32 and float64, the JAX loop and the native kernels): those of
tests/core/test_native.py with PML edges (obstacles, a density step, soft and hard sources,
viscous absorption; the isotropic stencil on rz and 2-D grids with and without face arrays) and a
standard-stencil rz scene with an r_hi layer. Prints max |new - old| / peak of the final field and
the probes per scene; exit status 1 if any exceeds n_steps * 16 * eps of its dtype.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

N_STEPS = 97


def _scenes():
    import jax.numpy as jnp

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "core"))
    import test_native as tn

    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver.sources import PointSources, ToneBurst

    for kind in ("conservative+pml", "homogeneous+pml", "absorbing+pml"):
        for dtype in ("float64", "float32"):
            yield f"{kind}|{dtype}", tn._scene(kind, dtype)
    for kind in ("rz pml", "rz obstacle+pml", "2d obstacle+speed map+pml", "2d pml+absorbing"):
        yield f"iso {kind}|float64", tn._iso_scene(kind, "float64")
    for dtype in ("float64", "float32"):
        g = make_grid(
            frequency_hz=50e3, cells_per_wavelength=10, c_max_m_s=343.0, shape=(48, 40), dtype=dtype, kind="rz"
        )
        src = PointSources(
            cells=[(10, j) for j in range(6)],
            signal=ToneBurst(50e3, 2),
            weights=jnp.linspace(0.7, 1.3, 6),
            lags_s=jnp.zeros(6),
        )
        med = Medium(343.0, jnp.where(tn.X > 30, 2.0, 1.2))
        yield f"rz std|{dtype}", (g, med, src, tn.SENS, Edges.axisymmetric("rigid", "pml", "pml", thickness_cells=6))


def outputs() -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    from difflattice.solver import simulate

    out = {}
    for key, (g, medium, src, sens, edges) in _scenes():
        for backend in ("jax", "native"):
            r = simulate(g, medium, src, sens, n_steps=N_STEPS, edges=edges, backend=backend, checkpoint=10)
            out[f"{key}|{backend}|p"] = np.asarray(r.final.pressure)
            out[f"{key}|{backend}|probes"] = np.asarray(r.probes)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--write", type=Path)
    g.add_argument("--compare", type=Path)
    args = ap.parse_args(argv)
    new = outputs()
    if args.write:
        np.savez(args.write, **new)
        print(f"wrote {len(new)} arrays to {args.write}")
        return 0
    old = dict(np.load(args.compare))
    bad = 0
    for key, got in new.items():
        ref = old[key]
        eps = float(np.finfo(np.float32 if "float32" in key else np.float64).eps)
        rel = float(np.abs(got - ref).max() / np.abs(ref).max())
        ok = rel <= N_STEPS * 16 * eps
        bad += not ok
        print(f"{key:48s} {rel:9.2e} {'ok' if ok else 'DIFFERS'}")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
