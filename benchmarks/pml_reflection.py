"""The PML's reflection, normal and oblique, in float64: the figures the layer's form must keep.

    python3 benchmarks/pml_reflection.py [--json OUT.json]

- normal incidence: `apps.validation.edge_reflection_db("pml")`, a plane-wave burst on the x_hi
  layer (20 cells, 20 cells per wavelength);
- 45 deg, 2-D: `apps.accuracy_wall.edge_sweep` (point source 4 wavelengths inside a 20-cell layer,
  20 cells per wavelength), its corner probe on the window's diagonal (and its axis probe);
- 45 deg, rz: the r_hi layer with its cylindrical correction (the case of
  tests/core/test_axisym_stability.py::test_radial_pml_absorbs_oblique_waves: 12 cells per
  wavelength, a 12-cell layer).

Each is the difference from a window too large to reach, in dB of the reference's peak. Run it
with another checkout on PYTHONPATH to compare two versions of the solver (the figures depend on
the scheme, not on the machine). Prints a table and one JSON line.
"""

from __future__ import annotations

import argparse
import json
import sys


def rz_oblique_db() -> float:
    import jax.numpy as jnp
    import numpy as np

    from difflattice.lattice import Edges
    from difflattice.lattice.grid import make_grid
    from difflattice.lattice.medium import Medium
    from difflattice.solver import Sensors, Stepper, run
    from difflattice.solver.sources import PointSources, ToneBurst

    ppw, L, W = 12, 12, 60
    nz, zs = 5 * W, W + L
    n_steps = int(3.0 * W / 0.7)

    def probe(nr):
        g = make_grid(
            frequency_hz=50e3,
            cells_per_wavelength=ppw,
            c_max_m_s=343.0,
            shape=(nz, nr),
            courant=0.7,
            dtype="float64",
            kind="rz",
        )
        src = PointSources(cells=[(zs, 0)], signal=ToneBurst(50e3, 3.0), weights=jnp.ones(1), lags_s=jnp.zeros(1))
        edges = Edges.axisymmetric("rigid", "rigid", "pml", thickness_cells=L)
        st = Stepper.build(g, Medium(343.0, 1.2), src, Sensors(probes=[(zs + W, 0)]), edges)
        return np.asarray(run(st, n_steps).probes)[:, 0]

    ref = probe(W + L + 2 * W)
    return float(20 * np.log10(np.abs(probe(W + L) - ref).max() / np.abs(ref).max()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write the figures to this file")
    args = ap.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    from difflattice.apps.accuracy_wall import edge_sweep
    from difflattice.apps.validation import edge_reflection_db

    normal = edge_reflection_db("pml", thickness_cells=20, cells_per_wavelength=20)
    sweep = edge_sweep(cells_per_wavelength=(20,), thicknesses_cells=(20,), dtype="float64", kinds=("pml",))
    row = next(r for r in sweep["rows"] if r["edge"] == "pml")
    out = {
        "normal_incidence_db": normal,
        "point_source_axis_db": row["reflection_db_axis"],
        "point_source_45deg_db": row["reflection_db_corner"],
        "rz_r_hi_45deg_db": rz_oblique_db(),
    }
    for k, v in out.items():
        print(f"{k:>24}  {v:8.1f} dB", file=sys.stderr)
    print(json.dumps(out))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
