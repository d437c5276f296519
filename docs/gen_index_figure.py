"""Draw the picture on the documentation's front page (docs/images/index.png), from the project:

- left: the pressure field of a 38.4 mm disc at 50 kHz in a rigid baffle, on the axisymmetric
  (r-z) lattice (the example of docs/index.md at 20 cells per wavelength, the meridian section
  mirrored about the axis) while its burst leaves the face;
- right: the lobe measured on the emulated rig (data/emulated/piston_disc) with the disc model
  fitted to it (`fitting/piston_disc.toml`, `--quick` settings) and the uniform piston it
  started from.

    .venv/bin/python docs/gen_index_figure.py            # about a minute on 2 cores

Not run by `docs/build.sh` (it fits); rerun it when the models change and commit the PNG.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
os.environ.setdefault("MPLBACKEND", "Agg")


def disc_field(cells_per_wavelength: float = 20.0):
    """The snapshot of the disc's field (mirrored about the axis), its step and the grid."""
    import numpy as np

    import difflattice as dl

    grid = dl.make_grid(
        frequency_hz=50e3, cells_per_wavelength=cells_per_wavelength, c_max_m_s=343.2, size_m=(0.06, 0.04), kind="rz"
    )
    disc = dl.disc_transducer(grid, radius_m=0.0192)
    edges = dl.Edges.axisymmetric(z_lo="rigid", thickness_cells=20)
    every = int(round(grid.steps_per_period))
    sensors = dl.Sensors(snapshot_every=every)
    n_steps = 9 * every
    result = dl.simulate(grid, dl.Medium(343.2, 1.204), disc, sensors, n_steps=n_steps, edges=edges)
    field = np.asarray(result.snapshots[-1])
    return np.concatenate([field[:, ::-1], field], axis=1), result.snapshot_steps[-1], grid


def fitted_lobe():
    """The measured lobe, the fitted disc model and the uniform piston (dB), from a quick fit."""
    from difflattice.apps.fitting import run_fit
    from difflattice.apps.jaxconfig import configure
    from difflattice.fit.config import load_config

    configure()  # float64, as the `fit` command runs

    with tempfile.TemporaryDirectory() as tmp:
        report = run_fit(load_config(ROOT / "fitting" / "piston_disc.toml"), out=tmp, quick=True, verbose=False)
    return report["model_curves"]["lobe"], report["fit"]["parameters"]


def main() -> None:
    import numpy as np
    from matplotlib.figure import Figure

    from difflattice import plots

    field, step, grid = disc_field()
    lobe, params = fitted_lobe()
    fig = Figure(figsize=(11, 4.2), layout="constrained")
    left, right = fig.subplots(1, 2, width_ratios=[1.25, 1])
    plots.field_image(
        field.T,
        grid.dx_m,
        every=1,
        step=step,
        dt_s=grid.dt_s,
        ax=left,
        colorbar=False,
        size_m=(2 * grid.size_m[1], grid.size_m[0]),
    )
    r_mm, z_mm = grid.size_m[1] * 1e3, grid.size_m[0] * 1e3
    left.images[0].set_extent((-r_mm, r_mm, 0.0, z_mm))  # the axis r = 0 in the middle
    left.set_xlim(-r_mm, r_mm)
    left.set_xlabel("r (mm), mirrored about the axis")
    left.set_ylabel("z (mm), rigid baffle at z = 0")
    left.set_title("a 38.4 mm disc at 50 kHz, r-z lattice")
    a = np.asarray(lobe["angle_deg"])
    peak = max(lobe["measured_db"])
    right.errorbar(
        a, np.asarray(lobe["measured_db"]) - peak, yerr=lobe["sigma_db"], fmt=".", ms=4, color="k", label="measured"
    )
    right.plot(a, np.asarray(lobe["model_db"]) - peak, color="C3", lw=1.6, label="fitted disc model")
    right.plot(
        a,
        np.asarray(lobe["uniform_model_db"]) - max(lobe["uniform_model_db"]),
        color="C0",
        lw=1,
        ls="--",
        label="uniform piston (start)",
    )
    d_mm = params.get("diameter_m", float("nan")) * 1e3
    right.set_title(f"lobe at {lobe['range_m']:g} m: fitted diameter {d_mm:.1f} mm")
    right.set_xlabel("angle (deg)")
    right.set_ylabel("level (dB re measured peak)")
    right.set_ylim(-45, 3)
    right.grid(True, alpha=0.3)
    right.legend(loc="upper left", fontsize=8)
    out = ROOT / "docs" / "images" / "index.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
