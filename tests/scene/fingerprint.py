"""Fingerprints of built scenes: what `Scene.build()` gives for a scene file at a cheap
resolution (grid, medium maps, sources, sensors, edges, far-field surface, run length), as plain
JSON data. Written with the scene code before the typed scene spec (running this file with that
code first on the path prints them; x64 on, as in the tests) and compared by
tests/test_scene_spec.py, so a refactor of the scene spec must build the same arrays.

Integer arrays (cells) are kept exactly (their sha256), and so is every scalar; float arrays as
their shape and three sums (plain, squared, and weighted by a fixed sequence), compared to a
relative 1e-6: a moved cell or a changed weight changes them by far more, while the last-bit
differences of another CPU's floating point (the medium maps are rasterised by XLA) do not."""

from __future__ import annotations

import glob
import hashlib
import json
import sys
import tomllib
from pathlib import Path

import numpy as np

SCENES = Path(__file__).resolve().parents[2] / "src" / "difflattice" / "scenes"

CHEAP_CPW = {2: 8.0, 3: 4.0}
"""Cells per wavelength of the fingerprinted builds, by the lattice's number of axes."""

EXTRA = {
    # an exported rz design's source: the transparent soft ring disc (injection given)
    "rz_soft_disc": """
[grid]
kind = "rz"
frequency_hz = 40000.0
cells_per_wavelength = 10.0
size_m = [0.06, 0.04]
[edges]
kind = "pml"
thickness_cells = 8
[[transducers]]
type = "disc"
centre_m = [0.02, 0.0]
diameter_m = 0.012
baffle = "none"
injection = "soft"
[[objects]]
shape = "polyline"
material = "rigid"
thickness_m = 0.001
points_m = [[0.018, 0.008], [0.03, 0.015]]
[sensors]
probes_m = [[0.04, 0.0], [0.04, 0.01]]
[farfield]
range_m = 1.0
angles_deg = [-90.0, 90.0, 1.0]
dispersion = "continuum"
[run]
n_steps = 40
""",
    # an rz disc in a can, and a 2d line with weights over a circle, a box cut by a box, and air
    "rz_can": """
[grid]
kind = "rz"
frequency_hz = 40000.0
cells_per_wavelength = 10.0
size_m = [0.05, 0.03]
[edges]
kind = "pml"
z_lo = "rigid"
[[transducers]]
type = "disc"
centre_m = [0.01, 0.0]
diameter_m = 0.01
baffle = "can"
can_depth_m = 0.004
can_wall_m = 0.001
signal = "cw"
[run]
duration_s = 1e-4
""",
    "line_air_objects": """
[grid]
frequency_hz = 40000.0
cells_per_wavelength = 10.0
size_m = [0.08, 0.06]
[air]
temperature_c = 25.0
humidity_pct = 40.0
[edges]
kind = "mur"
x_lo = "rigid"
[[transducers]]
centre_m = [0.03, 0.01]
diameter_m = 0.012
weights = [1.0, 0.5, 1.0]
lags_s = [0.0, 1e-6, 0.0]
direction_deg = 90.0
[[objects]]
shape = "circle"
centre_m = [0.05, 0.02]
radius_m = 0.004
material = "soft"
[[objects]]
shape = "box"
lo_m = [0.05, 0.035]
hi_m = [0.06, 0.05]
cut = { shape = "box", lo_m = [0.052, 0.04], hi_m = [0.058, 0.045] }
[sensors]
probes_m = [[0.07, 0.03]]
p_rms = true
arrival_threshold_pa = 0.01
[run]
n_steps = 30
[output]
show_steps = [10, 20]
""",
}
"""Scenes beside the shipped ones that reach the keys the shipped ones do not."""


def _fp(a) -> object:
    """One value's fingerprint (see the module docstring)."""
    if a is None or isinstance(a, (bool, int, str)):
        return a
    if isinstance(a, float):
        return float(a)
    if isinstance(a, (tuple, list)):
        return [_fp(v) for v in a]
    x = np.asarray(a)
    if x.dtype.kind in "iub":
        return {"shape": list(x.shape), "sha256": hashlib.sha256(x.astype("<i8").tobytes()).hexdigest()}
    x = x.astype(np.float64).ravel()
    w = np.sin(0.7 * np.arange(x.size) + 0.3)
    return {"shape": list(np.shape(a)), "sums": [float(x.sum()), float((x * x).sum()), float((x * w).sum())]}


def fingerprint(built) -> dict:
    """The fingerprint of a `BuiltScene`."""
    g, m, s, e = built.grid, built.medium, built.sensors, built.edges
    t = (np.arange(1, 41) * g.dt_s).astype(np.float64)
    out = {
        "grid": _fp([list(g.shape), g.dx_m, g.dt_s, g.courant, str(g.stencil), str(g.dtype)]),
        "medium": {
            k: _fp(getattr(m, k))
            for k in ("sound_speed_m_s", "density_kg_m3", "rigid", "soft", "boundary_model", "absorption_db_per_m")
        },
        "air": None
        if m.air is None
        else _fp([float(m.air.temperature_c), float(m.air.humidity_pct), float(m.air.pressure_pa)]),
        "sources": [
            {
                "cells": _fp(np.asarray(src.cells_array)),
                "weights": _fp(src.weights),
                "lags_s": _fp(src.lags_s),
                "injection": src.injection,
                "signal": _fp(np.asarray(src.signal(t))),
            }
            for src in built.sources
        ],
        "sensors": {
            "probes": _fp(np.asarray(s.probes)),
            "phasor_cells": _fp(np.asarray(s.phasor_cells)),
            "flags": _fp([s.p_max, s.p_rms, s.arrival_threshold_pa, s.snapshot_every]),
            "slices": repr(s.snapshot_slices),
        },
        "edges": [getattr(e, k) for k in ("x_lo", "x_hi", "y_lo", "y_hi", "z_lo", "z_hi", "thickness_cells")],
        "n_steps": built.n_steps,
        "contour": None if built.contour is None else _fp(np.asarray(built.contour.cells)),
        "farfield_source": built.farfield_source,
        "show_steps": [int(v) for v in built.show_steps],
        "render_every": built.render_every,
        "receivers": [list(r) for r in built.receivers],
    }
    return json.loads(json.dumps(out))


def scene_names() -> list[str]:
    return sorted(Path(f).stem for f in glob.glob(str(SCENES / "*.toml"))) + sorted(EXTRA)


def build(name: str):
    """The scene `name` (shipped file or `EXTRA`) at its cheap resolution, built."""
    from difflattice.scene import load_scene, parse_scene

    if name in EXTRA:
        scene = parse_scene(tomllib.loads(EXTRA[name]), f"<{name}>")
    else:
        scene = load_scene(SCENES / f"{name}.toml")
    scene = scene.at_resolution(CHEAP_CPW[scene.kind.ndim])
    return scene.build(available_bytes=1 << 40)


if __name__ == "__main__":
    import jax

    import difflattice

    jax.config.update("jax_enable_x64", True)  # as tests/conftest.py sets it for the tests
    jax.config.update("jax_numpy_rank_promotion", "raise")

    print(f"# difflattice from {Path(difflattice.__file__).parent}", file=sys.stderr)
    print(json.dumps({n: fingerprint(build(n)) for n in (sys.argv[1:] or scene_names())}, indent=None))
