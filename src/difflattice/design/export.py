"""A design as a scene TOML file that `difflattice simulate` accepts (checked with `scene.load_scene`).

The walls are written as polylines (their centre lines and thickness), rasterised "smooth" as in
the design, in air at 20 C with the conservative boundary model; grid, transducer, burst, PML and
run length are the design problem's, so the scene reproduces the simulated design. An rz design
becomes an rz scene whose disc is the design's transparent soft ring disc (`injection = "soft"`),
with the wall's meridian half (r >= 0) as a polyline in (z, r). Its
[farfield] section asks for the design's lobe (range, angle step): the scene runner's surface
encloses the transducer and every wall (`Scene.build`), as the design's own contour does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .problem import DesignProblem


def _num(v) -> str:
    return repr(float(v))


def _pts(a) -> str:
    rows = [f"  [{_num(x)}, {_num(y)}]," for x, y in np.asarray(a, float)]
    return "[\n" + "\n".join(rows) + "\n]"


def scene_toml(problem: DesignProblem, params, *, title: str = "", snapshot_every_steps: int = 50) -> str:
    """TOML text of the scene (see the module docstring)."""
    g = problem.grid
    shape = params.shape(problem.anchor_m)
    rz = problem.lattice.ring_metric
    lines = [
        f"# {title or 'Design exported by difflattice.design'}",
        f"# {problem.kind} parameters: " + ", ".join(f"{k} = {v:.6g}" for k, v in params.as_dict().items()),
        "[grid]",
        *(['kind = "rz"'] if rz else []),
        f"frequency_hz = {_num(g.frequency_hz)}",
        f"cells_per_wavelength = {_num(g.cells_per_wavelength)}",
        f"shape = [{g.shape[0]}, {g.shape[1]}]",
        f"courant = {_num(g.courant)}",
        f'dtype = "{g.dtype}"',
        "",
        "[medium]",
        'background = "air"',
        "temperature_c = 20.0",
        f'boundary_model = "{"speed_zero" if problem.wall == "soft" else "conservative"}"',
        'rasterise = "smooth"',
        "",
        "[edges]",
        'kind = "pml"',
        f"thickness_cells = {problem.pml_cells}",
        "",
        "[[transducers]]",
        'name = "transducer"',
        f"centre_m = [{_num(problem.anchor_m[0])}, {_num(problem.anchor_m[1])}]",
        *(_disc(problem) if rz else [f"n_cells = {problem.n_cells}", f"direction_deg = {_num(problem.direction_deg)}"]),
        'signal = "burst"',
        f"cycles = {_num(problem.cycles)}",
        'window = "hann"',
        "",
    ]
    walls = shape.walls() if hasattr(shape, "walls") else (shape.wall(),)
    if rz:  # the meridian half-plane r >= 0: the mirror wall of a horn (r < 0) is not on the grid
        walls = tuple(w for w in walls if float(np.max(np.asarray(w.points_m)[:, 1])) > 0)
    for w in walls:
        lines += [
            "[[objects]]",
            'shape = "polyline"',
            f'material = "{problem.wall}"',
            f"thickness_m = {_num(w.thickness_m)}",
            f"points_m = {_pts(w.points_m)}",
            "",
        ]
    step = problem.angles_deg[1] - problem.angles_deg[0]
    lines += [
        "[sensors]",
        "p_max = true",
        f"snapshot_every_steps = {snapshot_every_steps}",
        "",
        "[farfield]",
        f"range_m = {_num(problem.range_m)}",
        f"angles_deg = [-90.0, 90.0, {_num(step)}]",
        'dispersion = "continuum"  # as the design evaluated its lobe',
        "",
        "[run]",
        f"n_steps = {problem.n_steps}",
        "",
    ]
    return "\n".join(lines)


def _disc(problem: DesignProblem) -> list[str]:
    """An rz design's source as a scene disc: the transparent soft ring disc the design simulated."""
    return [
        'type = "disc"',
        f"diameter_m = {_num(problem.face_m)}",
        'baffle = "none"',
        'injection = "soft"  # transparent soft ring sources, as the design (not the default velocity piston)',
    ]


def write_scene(problem: DesignProblem, params, path: str | Path, **kwargs) -> Path:
    """Write the scene file and check that it loads (raises `SceneError` if not)."""
    from ..scene.model import load_scene

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(scene_toml(problem, params, **kwargs))
    load_scene(path)
    return path
