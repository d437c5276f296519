"""`difflattice accuracy --case dispersion3d`: the 3-D stencils' phase speed along the axes and
the face and body diagonals, measured from simulated waves.

A continuous sine from a point source in the corner cell of a box whose three low sides are
rigid (mirrors: the octant of a source cluster centred on the corner) and whose high sides are
PML; the pressure at two ranges along each direction, fitted to a sine of the drive frequency
(least squares over a steady window of whole periods), gives the phase advance between them and
so the phase speed, with no dispersion formula involved (the continuum wavenumber only picks the
whole number of cycles between the ranges). Each row sets it beside the leapfrog's dispersion
relation for that stencil (`observe.analytic3d.phase_velocity_3d`), the reference the
measurement must reproduce, and the scheme's work per simulated wavelength of travel.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..lattice.kinds import VOLUME, StencilKind

DIRECTIONS = {"axis": (1, 0, 0), "face_diagonal": (1, 1, 0), "body_diagonal": (1, 1, 1)}
SCHEMES = {s: VOLUME.default_courant_for(s) for s in ("wide", "isotropic", "standard")}  # stencil -> default courant
RESOLUTIONS = (6.0, 7.0, 8.0, 12.0)
FILE = "accuracy_dispersion3d.json"


@dataclass(frozen=True)
class DispersionRow:
    """One row of `accuracy_dispersion3d.json` (phase speeds relative to the medium's)."""

    scheme: str
    courant: float
    cells_per_wavelength: float
    direction: str
    phase_speed_error: float
    """Measured (simulated) phase speed / medium speed - 1."""
    phase_speed_error_formula: float
    """The same from the leapfrog's dispersion relation (`analytic3d`)."""
    range_cells: tuple[float, float]
    work_cell_updates_per_wavelength: float
    """Stencil points x time steps per wavelength of travel, per cell of a wavelength cube:
    ``points * (cpw / courant) * cpw^3`` (the cost to carry one wavelength-cube of field one
    wavelength)."""


POINTS = {"wide": 25, "isotropic": 19, "standard": 7}


def _sine_fit(sig: np.ndarray, omega: float, steps: np.ndarray) -> complex:
    """Complex amplitude A of ``Re(A exp(-i omega n))`` fitted (least squares, with a constant) to `sig`."""
    basis = np.stack([np.cos(omega * steps), np.sin(omega * steps), np.ones_like(steps, dtype=float)], 1)
    (a, b, _), *_ = np.linalg.lstsq(basis, sig, rcond=None)
    return complex(a, b)  # Re((a + i b) exp(-i w n)) = a cos + b sin


def measure(
    scheme: StencilKind, cells_per_wavelength: float, *, far_wavelengths: float = 6.0, pml_cells: int = 12
) -> list[DispersionRow]:
    """Simulate one scheme at one resolution (float64) and measure the three directions."""
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    from ..lattice import Edges
    from ..lattice.grid import make_grid
    from ..lattice.medium import Medium
    from ..observe.analytic3d import phase_velocity_3d
    from ..solver import Sensors, simulate
    from ..solver.sources import ContinuousWave, PointSources

    courant = SCHEMES[scheme]
    cpw = cells_per_wavelength
    r1 = 2.0 * cpw  # first range, cells: two wavelengths out
    r2 = r1 + far_wavelengths * cpw
    n = int(math.ceil(r2 + 4)) + pml_cells
    shape = (n, n, n)
    grid = make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=cpw,
        c_max_m_s=343.0,
        shape=shape,
        courant=courant,
        dtype="float64",
        kind="3d",
        stencil=scheme,
    )
    edges = Edges(
        x_lo="rigid", x_hi="pml", y_lo="rigid", y_hi="pml", z_lo="rigid", z_hi="pml", thickness_cells=pml_cells
    )
    probes: list[tuple[int, ...]] = []
    ranges = {}
    for name, d in DIRECTIONS.items():
        u = np.asarray(d, float) / np.linalg.norm(d)
        # cells along the direction from the source cluster's centre (-1/2, -1/2, -1/2)
        cells = [np.rint(u * r - 0.5 + 0.5 * (u == 0)).astype(int) for r in (r1, r2)]
        pos = [np.linalg.norm(c + 0.5) for c in cells]
        ranges[name] = (len(probes), pos)
        probes += [tuple(int(v) for v in c) for c in cells]
    omega = 2 * math.pi * courant / cpw  # rad/step
    spp = cpw / courant
    settle = r2 / courant + 12 * spp
    window = int(round(10 * spp))
    n_steps = int(settle) + window
    src = PointSources(
        cells=np.zeros((1, 3), int),
        signal=ContinuousWave(40e3, ramp_cycles=3.0),
        weights=jnp.ones(1),
        lags_s=jnp.zeros(1),
    )
    res = simulate(
        grid, Medium(343.0, 1.2), src, Sensors(probes=np.asarray(probes)), n_steps=n_steps, edges=edges, preflight="off"
    )
    rec = np.asarray(res.probes)
    steps = np.arange(n_steps - window + 1, n_steps + 1, dtype=float)
    rows = []
    for name, (i0, (p1, p2)) in ranges.items():
        a1 = _sine_fit(rec[-window:, i0], omega, steps)
        a2 = _sine_fit(rec[-window:, i0 + 1], omega, steps)
        k_cont = omega / courant
        dphi = float(np.angle(a2 / a1))  # phase advance in (-pi, pi]
        dphi += 2 * math.pi * round((k_cont * (p2 - p1) - dphi) / (2 * math.pi))
        c_meas = omega * (p2 - p1) / dphi
        c_form = float(phase_velocity_3d(omega, courant, DIRECTIONS[name], stencil=scheme))
        rows.append(
            DispersionRow(
                scheme=scheme,
                courant=courant,
                cells_per_wavelength=cpw,
                direction=name,
                phase_speed_error=float(c_meas / courant - 1),
                phase_speed_error_formula=c_form / courant - 1,
                range_cells=(round(float(p1), 3), round(float(p2), 3)),
                work_cell_updates_per_wavelength=POINTS[scheme] * (cpw / courant) * cpw**3,
            )
        )
    return rows


def sweep(
    cells_per_wavelength=RESOLUTIONS,
    schemes: tuple[StencilKind, ...] = ("wide", "isotropic", "standard"),
    *,
    far_wavelengths: float = 6.0,
) -> list[DispersionRow]:
    """Every scheme at every resolution, printing each row as it comes."""
    rows = []
    for scheme in schemes:
        for cpw in cells_per_wavelength:
            for r in measure(scheme, float(cpw), far_wavelengths=far_wavelengths):
                print(
                    f"{r.scheme:9s} cpw {r.cells_per_wavelength:5.1f} {r.direction:14s} measured "
                    f"{100 * r.phase_speed_error:+.3f} %  formula {100 * r.phase_speed_error_formula:+.3f} %",
                    flush=True,
                )
                rows.append(r)
    return rows


def write(rows: list[DispersionRow], out_dir: str | Path) -> Path:
    """DIR/accuracy_dispersion3d.json: the rows and, per scheme, the worst direction at each resolution."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    worst: dict[str, dict[str, float]] = {}
    for r in rows:
        w = worst.setdefault(r.scheme, {})
        key = f"{r.cells_per_wavelength:g}"
        w[key] = max(w.get(key, 0.0), abs(r.phase_speed_error))
    doc = {
        "what": "3-D phase speed along axis, face and body diagonals: simulated (CW point source, phase "
        "between two ranges) beside the leapfrog's dispersion relation",
        "default_scheme": VOLUME.default_stencil,
        "rows": [asdict(r) for r in rows],
        "worst_abs_error_by_cpw": worst,
    }
    path = out / FILE
    path.write_text(json.dumps(doc, indent=1) + "\n")
    return path
