"""Each surface's echo isolated by a difference of runs (`apps.echoes_isolated`): the arrival
estimator against bursts placed at known delays (no lattice), the scene without a surface, and on
a small lattice a wall's isolated echo against its image-source delay on the lattice.

Tolerances. The estimator (envelope peak of the matched-filtered echo, parabolic refinement) is
exact for a symmetric envelope up to the parabola's bias, ~1e-4 sample for the 16-period
matched envelope sampled 7 times a period: 1e-3 period is asserted. On the lattice the model
(the drive carried along the image path with the lattice's dispersion relation, the one-step
lead of the soft source, the floor's image paths) is exact to round-off for a plane wave; what it
leaves out is the 4 mm disc's aperture (path spread a^2 / 4 d: 2e-4 period), float32 rounding
(1e-6 of the echo) and the diffraction from the wall's edges where the window's PML truncates it
(edge paths 1.2 wavelengths and more longer, a few % of the specular echo: a shift of the
envelope peak of at most amplitude x delay, ~0.05 period). Hence 0.1 period, the issue's figure,
with that budget (measured: +0.005 period)."""

import dataclasses
import json
import math

import numpy as np
import pytest

from difflattice.apps import echoes_isolated as ei
from difflattice.lattice.grid import make_grid
from difflattice.lattice.kinds import VOLUME
from difflattice.observe.analytic3d import group_velocity_3d
from difflattice.scene import load_scene
from difflattice.solver.sources import ToneBurst

WALL = """
[grid]
kind = "3d"
frequency_hz = 40000.0
cells_per_wavelength = 6.0
size_m = [0.13, 0.1, 0.09]
dtype = "float32"

[medium]
background = "air"
rasterise = "hard"

[edges]
kind = "pml"
thickness_cells = 12
x_hi = "rigid"
z_lo = "rigid"

[[transducers]]
name = "sonar"
type = "disc"
centre_m = [0.03, 0.05, 0.006]
axis = [1.0, 0.0, 0.0]
diameter_m = 0.004
signal = "burst"
cycles = 8.0
receive = true
gate_start_s = 0.00025

[[objects]]
name = "post"
shape = "cylinder"
material = "rigid"
centre_m = [0.09, 0.02, 0.0]
axis = [0.0, 0.0, 1.0]
radius_m = 0.006
length_m = 0.3

[sensors]
p_max = false

[run]
duration_s = 0.001
"""


def _grid(shape=(64, 8, 8)):
    return make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=6.0,
        c_max_m_s=343.21,
        shape=shape,
        courant=0.86,
        kind="3d",
        stencil="isotropic",
    )


def test_estimator_recovers_known_delays():
    """Bursts shifted by fractional delays (sampled from the drive, the soft source's one-step lead
    included) come back as their times of flight to 1e-3 period, matched or raw; the model at the
    air's speed gives path / c."""
    g = _grid()
    dt, f0 = g.dt_s, g.frequency_hz
    n = 600
    t = np.arange(1, n + 1) * dt
    burst = ToneBurst(f0, 8.0)
    ref = np.asarray(burst(t))[: int(math.ceil(8 / f0 / dt)) + 2]
    for tau_steps in (150.0, 151.37, 200.5):
        echo = np.asarray(burst(t + dt - tau_steps * dt))  # the wave leads the drive by one step
        for matched in (True, False):
            lag, _ = ei.arrival_lag(echo, ref, tau_steps - 20, tau_steps + 20, matched=matched)
            assert (lag + 1 - tau_steps) * dt * f0 == pytest.approx(0.0, abs=1e-3)
    path = 0.31
    for matched in (True, False):
        lag = ei.model_lag_steps(g, ref, n, [path], [1.0], (1.0, 0.0, 0.0), lattice=False, matched=matched)
        assert lag * dt == pytest.approx(path / 343.21, abs=1e-3 / f0)


def test_scene_without_a_surface(tmp_path):
    """An object is left out; a rigid window side is moved out behind the absorbing layer (the
    window grown by its depth and half a burst), a low side by moving everything."""
    p = tmp_path / "wall.toml"
    p.write_text(WALL.replace('z_lo = "rigid"', 'z_lo = "rigid"\ny_lo = "rigid"'))
    scene = load_scene(p)
    dx = 343.21 / (40e3 * 6.0)
    g = _grid(tuple(int(round(v / dx)) for v in scene.grid.size_m))  # as the scene builds it, no medium
    names = {s["surface"]: s for s in ei.echoes3d.surfaces(scene, g)}
    assert {"post", "wall x_hi", "wall y_lo"} <= set(names)
    assert ei.without(scene, g, names["post"], 8.0).objects == ()
    hi = ei.without(scene, g, names["wall x_hi"], 8.0)
    grow = 12 + 24 + 2
    assert hi.grid.shape == (g.shape[0] + grow, g.shape[1], g.shape[2]) and hi.edges.x_hi == "pml"
    assert hi.transducers == scene.transducers
    lo = ei.without(scene, g, names["wall y_lo"], 8.0)
    assert lo.grid.shape[1] == g.shape[1] + grow and lo.edges.y_lo == "pml"
    dy = grow * g.dx_m
    assert lo.transducers[0].centre_m[1] == pytest.approx(0.05 + dy)
    assert lo.objects[0].centre_m == pytest.approx((0.09, 0.02 + dy, 0.0))


@pytest.mark.slow
def test_isolated_wall_echo_within_a_tenth_of_a_period(tmp_path):
    """A wall 0.1 m ahead of a 4 mm disc 6 mm above a rigid floor: the wall's echo isolated (the
    scene minus the scene with the wall moved out) arrives within 0.1 period of its image-source
    delay on the lattice (module docstring: the budget), and after the delay in air by what the
    lattice's group velocity along x says. The disc sits low so that the path via the floor's
    image is within 0.05 wavelength of the direct one (at 20.5 mm, as in the corridor, the two are
    half a wavelength apart at this range and nearly cancel at the drive frequency: no envelope
    peak survives that). The post is left out: 24 mm off the axis it shadows the wall's first
    Fresnel zone, and its double bounces (post - wall, 2 wavelengths longer) belong to the wall's
    difference too; neither is in an image-source delay (measured in docs/three_d.md)."""
    p = tmp_path / "wall.toml"
    p.write_text(WALL)
    scene = dataclasses.replace(load_scene(p), objects=())
    doc = ei.isolate_echoes(scene, tmp_path / "out", only=["wall x_hi"])
    (e,) = doc["echoes"]
    assert e["resolved"]
    assert abs(e["error_periods"]) < 0.1, e
    stencil = VOLUME.default_stencil  # the scene names none: the 3-D default, at its default courant
    g = make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=6.0,
        c_max_m_s=343.21,
        shape=(64, 8, 8),
        courant=VOLUME.default_courant_for(stencil),
        kind="3d",
        stencil=stencil,
    )
    vg = float(group_velocity_3d(g.omega, g.courant, (1.0, 0.0, 0.0), stencil=stencil)) / g.courant
    expect_air = e["path_m"] / 343.21 * (1 / vg - 1) * 40e3  # periods late over the path
    assert e["error_periods_air"] == pytest.approx(expect_air, abs=0.1)
    assert (tmp_path / "out" / "echoes_isolated.png").exists()


EDGE = (
    WALL.replace('x_hi = "rigid"\n', "")
    .replace(
        "centre_m = [0.03, 0.05, 0.006]\naxis = [1.0, 0.0, 0.0]",
        "centre_m = [0.035, 0.035, 0.006]\naxis = [1.0, 1.0, 0.0]",
    )
    .replace(
        'name = "post"\nshape = "cylinder"\nmaterial = "rigid"\ncentre_m = [0.09, 0.02, 0.0]\naxis = [0.0, 0.0, 1.0]\n'
        "radius_m = 0.006\nlength_m = 0.3",
        'name = "block"\nshape = "box"\nmaterial = "rigid"\ncentre_m = [0.1387, 0.1387, 0.0]\nsize_m = [0.1226, 0.1226, 0.4]',
    )
    .replace("size_m = [0.13, 0.1, 0.09]", "size_m = [0.12, 0.12, 0.08]")
    .replace("duration_s = 0.001", "duration_s = 0.0008")
)


@pytest.mark.slow
def test_isolated_edge_echo_arrives_at_the_edge_path_delay(tmp_path):
    """A rigid block whose vertical edge (0.0774, 0.0774) faces a 4 mm disc at (0.035, 0.035), 6 mm
    above a rigid floor, its two faces running off into the PML: neither face's foot of the normal
    lies on it, so there is no specular echo (`first_arrival` = "edge") and the first arrival is
    the edge-diffracted wave along the shortest path via the edge, 2 x 60 mm. Its isolated echo
    arrives within 0.1 period of that path's delay on the lattice (same model as the wall: the
    drive carried along the path with the dispersion relation along the diagonal; Keller's edge
    ray multiplies the spectrum by a real, band-smooth factor and a constant phase, which leave the
    envelope's peak where it is), and after the air's delay by what the lattice's group velocity
    along the diagonal says. Left out of the model: the diffraction coefficient's 1/(k r)
    corrections (k r = 44), the edge's end in the PML above (5 wavelengths of path later), the
    staircase edge (the rasterised offset is in the path); measured -0.03 period."""
    p = tmp_path / "edge.toml"
    p.write_text(EDGE)
    scene = load_scene(p)
    doc = ei.isolate_echoes(scene, tmp_path / "out", only=["block"])
    (e,) = doc["echoes"]
    assert e["first_arrival"] == "edge"
    assert e["point_m"][:2] == pytest.approx([0.0774, 0.0774], abs=1e-6)
    assert e["resolved"]
    assert abs(e["error_periods"]) < 0.1, e
    stencil = VOLUME.default_stencil
    g = make_grid(
        frequency_hz=40e3,
        cells_per_wavelength=6.0,
        c_max_m_s=343.21,
        shape=(64, 8, 8),
        courant=VOLUME.default_courant_for(stencil),
        kind="3d",
        stencil=stencil,
    )
    vg = float(group_velocity_3d(g.omega, g.courant, e["direction"], stencil=stencil)) / g.courant
    expect_air = e["path_m"] / 343.21 * (1 / vg - 1) * 40e3
    assert e["error_periods_air"] == pytest.approx(expect_air, abs=0.1)


@pytest.mark.slow
def test_an_isolation_cut_short_keeps_the_surfaces_done(tmp_path):
    """Interrupted while isolating its second surface (here by the progress callback; in the GPU
    session by a time limit), `isolate_echoes` leaves echoes_isolated.json and .npz with the first
    surface measured and `complete: false`; measuring that file again (`saved=`) gives the same
    table without a run."""
    p = tmp_path / "wall.toml"
    p.write_text(WALL)
    scene = load_scene(p)

    def log(message):
        if message.startswith("isolating") and (tmp_path / "out" / "echoes_isolated.json").exists():
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        ei.isolate_echoes(scene, tmp_path / "out", log=log)
    doc = json.loads((tmp_path / "out" / "echoes_isolated.json").read_text())
    assert doc["complete"] is False and len(doc["echoes"]) == 1
    again = ei.isolate_echoes(scene, tmp_path / "again", saved=tmp_path / "out" / "echoes_isolated.npz")
    assert again["complete"] is True
    assert [e["surface"] for e in again["echoes"]] == [doc["echoes"][0]["surface"]]
    assert again["echoes"][0]["error_periods"] == pytest.approx(doc["echoes"][0]["error_periods"], abs=1e-9)


@pytest.mark.slow
def test_the_run_without_a_surface_stops_after_its_window(tmp_path):
    """The run without a surface stops a burst after the fit's window (two bursts after the echo
    starts): the isolated echo is the full-length difference up to there (the same steps, float32
    rounding apart), zero after it, and the row says where it ends."""
    from difflattice.apps.scene3d_run import run_scene3d

    p = tmp_path / "wall.toml"
    p.write_text(WALL.replace("duration_s = 0.001", "duration_s = 0.0016"))  # a record that goes on after the window
    scene = load_scene(p)
    doc = ei.isolate_echoes(scene, tmp_path / "out", only=["wall x_hi"])
    (row,) = doc["echoes"]
    dt = doc["dt_s"]
    burst = doc["burst_cycles"] / (doc["frequency_hz"] * dt)
    m = int(round(row["recorded_until_s"] / dt))
    with np.load(tmp_path / "out" / "echoes_isolated.npz") as z:
        assert list(z["recorded_steps"]) == [m]
        a, echo = z["a_scan"], z["echoes"][0]
    assert row["delay_lattice_s"] / dt + 3 * burst <= m < len(a) - burst  # cut, after the window
    grid = scene.build().grid
    s = next(s for s in ei.echoes3d.surfaces(scene, grid) if s["surface"] == "wall x_hi")
    _, _, a_long, _ = ei._receiver(run_scene3d(ei.without(scene, grid, s, 8.0), quiet=True))  # not cut
    assert len(a_long) == len(a)
    assert np.max(np.abs(echo[:m] - (a[:m] - a_long[:m]))) <= 1e-6 * np.max(np.abs(a)) and not np.any(echo[m:])


def test_a_walls_echo_between_a_rigid_floor_and_ceiling(tmp_path):
    """The wall of `test_isolated_wall_echo_within_a_tenth_of_a_period` with a rigid ceiling as
    well (z_hi): floor and ceiling make a guide (`echoes3d.find_guides`) and the wall's echo has
    copies via the transducer's images in them; the one via the ceiling's (2 H - 2 u above it, H
    the window's height, u the disc's height over the floor) adds ~7 periods to the round trip,
    inside the burst, so it is in the model echo (weighted by the disc's directivity at its tilt),
    and the isolated echo's first arrival is within 0.1 period of the image-source delay (the same
    budget as the open scene's; without the ceiling's image the model misses a copy of 0.8 of the
    direct echo's amplitude in the fit's window)."""
    p = tmp_path / "wall.toml"
    p.write_text(WALL.replace('z_lo = "rigid"\n', 'z_lo = "rigid"\nz_hi = "rigid"\n'))
    scene = dataclasses.replace(load_scene(p), objects=())
    doc = ei.isolate_echoes(scene, tmp_path / "out", only=["wall x_hi"])
    (e,) = doc["echoes"]
    built = scene.build()
    grid = built.grid
    src = built.sources[built.receivers[0].source]  # the disc's centre: the mean of its cells
    centre = np.average(np.asarray(src.cells_array, float), axis=0, weights=np.abs(np.asarray(src.weights)))
    height = grid.shape[2] * grid.dx_m
    u = centre[2] * grid.dx_m + 0.5 * grid.dx_m
    ceiling = math.hypot(e["path_m"] - 2 * e["rasterised_offset_m"], 2 * height - 2 * u) + 2 * e["rasterised_offset_m"]
    assert any(abs(q - ceiling) < 1e-9 for q in e["merged_paths_m"]), (ceiling, e["merged_paths_m"])
    assert abs(e["error_periods"]) < 0.1, e
