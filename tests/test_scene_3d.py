"""3-D scene files through the one scene path (`scene.schema` + `scene.model`) and
`difflattice simulate`: a file builds the same lattice as the library by hand (bitwise), the 3-D
stability limit and the memory estimate refuse what cannot run, the command writes the A-scan and
the images (its echo delay against the round trip 2 d / c), and a 2-D scene builds nothing 3-D
(and a 3-D one nothing 2-D)."""

import json
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.cli import main
from difflattice.scene import SceneError, SceneTooLargeError, load_scene, parse_scene

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "data" / "scenes"

TINY = """
[grid]
kind = "3d"
stencil = "standard"
frequency_hz = 40000.0
cells_per_wavelength = 8.0
size_m = [0.03, 0.025, 0.02]

[medium]
rasterise = "smooth"

[edges]
kind = "pml"
thickness_cells = 4
z_lo = "rigid"

[[transducers]]
type = "disc"
centre_m = [0.008, 0.0125, 0.01]
axis = [1.0, 0.2, 0.0]
diameter_m = 0.0086
receive = true

[[objects]]
shape = "halfspace"
point_m = [0.024, 0.0125, 0.01]
normal = [-0.94, 0.34, 0.0]

[[objects]]
shape = "sphere"
centre_m = [0.016, 0.006, 0.01]
radius_m = 0.002

[[objects]]
shape = "box"
centre_m = [0.016, 0.019, 0.01]
size_m = [0.003, 0.002, 0.004]
angles_deg = [30.0, 0.0, 10.0]

[[objects]]
shape = "cylinder"
centre_m = [0.02, 0.0125, 0.004]
axis = [0.0, 1.0, 1.0]
radius_m = 0.001
length_m = 0.008

[sensors]
probes_m = [[0.012, 0.0125, 0.01]]

[run]
duration_s = 1e-4
"""


def _tiny(tmp_path, text=TINY) -> Path:
    f = tmp_path / "tiny3d.toml"
    f.write_text(text)
    return f


def test_scene_file_builds_the_same_lattice_as_by_hand(tmp_path):
    from difflattice.lattice import Edges, Medium, air, make_grid
    from difflattice.lattice.geometry3d import Cylinder, HalfSpace, OrientedBox, Sphere, rasterise3d
    from difflattice.solver.sources import ToneBurst, disc_transducer_3d
    from difflattice.solver.stepper import Stepper

    b = load_scene(_tiny(tmp_path)).build()

    bg = air(20.0)
    grid = make_grid(
        frequency_hz=40e3, cells_per_wavelength=8.0, c_max_m_s=bg.speed_m_s, size_m=(0.03, 0.025, 0.02), kind="3d"
    )

    def a(v):
        return jnp.asarray(v, dtype=float)

    solids = [
        HalfSpace(a([0.024, 0.0125, 0.01]), a([-0.94, 0.34, 0.0])),
        Sphere(a([0.016, 0.006, 0.01]), a(0.002)),
        OrientedBox(a([0.016, 0.019, 0.01]), a([0.003, 0.002, 0.004]), a([30.0, 0.0, 10.0])),
        Cylinder(a([0.02, 0.0125, 0.004]), a([0.0, 1.0, 1.0]), a(0.001), a(0.008)),
    ]
    occ = [rasterise3d(s, grid, "smooth") for s in solids]
    free = 1 - occ[0]
    for o in occ[1:]:
        free = free * (1 - o)
    medium = Medium(bg.speed_m_s, bg.density_kg_m3, rigid=jnp.asarray(1 - free, grid.jnp_dtype))
    edges = Edges(x_lo="pml", x_hi="pml", y_lo="pml", y_hi="pml", z_lo="rigid", z_hi="pml", thickness_cells=4)
    src = disc_transducer_3d(
        grid, (0.008, 0.0125, 0.01), (1.0, 0.2, 0.0), diameter_m=0.0086, signal=ToneBurst(40e3, 5.0)
    )

    assert b.grid == grid and grid.courant == 0.577
    assert b.edges == edges
    assert b.n_steps == math.ceil(1e-4 / grid.dt_s)
    (s,) = b.sources
    assert np.array_equal(s.cells_array, src.cells_array)
    assert np.array_equal(np.asarray(s.weights), np.asarray(src.weights))
    assert np.array_equal(np.asarray(s.lags_s), np.asarray(src.lags_s))
    assert np.array_equal(np.asarray(b.medium.rigid), np.asarray(medium.rigid))
    # the probe, then the receiving transducer's cells
    probes = np.asarray(b.sensors.probes)
    assert np.array_equal(probes[0], np.rint(np.array([0.012, 0.0125, 0.01]) / grid.dx_m))
    (r,) = b.receivers
    assert np.array_equal(probes[r.start : r.stop], src.cells_array)
    lat_file = Stepper.build(b.grid, b.medium, b.sources, b.sensors, b.edges).lattice
    lat_hand = Stepper.build(grid, medium, (src,), b.sensors, edges).lattice
    assert jax.tree_util.tree_structure(lat_file) == jax.tree_util.tree_structure(lat_hand)
    for x, y in zip(jax.tree_util.tree_leaves(lat_file), jax.tree_util.tree_leaves(lat_hand)):
        assert np.array_equal(np.asarray(x), np.asarray(y))


def test_fit_report_rings_drive_the_disc(tmp_path):
    from difflattice.solver.sources import disc_transducer_3d, rings_from_fit_report

    report = {"parameters": {"weights_raw": [1.0, 0.8, 0.3], "lags_s": [0.0, 1e-6, 2e-6], "diameter_m": 0.0086}}
    report["model"] = {"dx_m": 0.0086 / 6}
    (tmp_path / "report.json").write_text(json.dumps(report))
    text = TINY.replace("diameter_m = 0.0086\nreceive = true", 'fit_report = "report.json"\nreceive = true')
    b = load_scene(_tiny(tmp_path, text)).build()
    rings = rings_from_fit_report(tmp_path / "report.json")
    d = rings.pop("diameter_m")
    src = disc_transducer_3d(b.grid, (0.008, 0.0125, 0.01), (1.0, 0.2, 0.0), diameter_m=d, rings=rings)
    assert np.array_equal(np.asarray(b.sources[0].weights), np.asarray(src.weights))
    assert np.array_equal(np.asarray(b.sources[0].lags_s), np.asarray(src.lags_s))
    assert float(np.ptp(np.asarray(src.lags_s))) > 0


@pytest.mark.parametrize(
    "kind, courant, limit",
    [("3d", 0.58, "1/sqrt(3) = 0.5774"), ("2d", 0.71, "1/sqrt(2) = 0.7071")],
)
def test_courant_above_the_limit_is_refused_in_one_line(kind, courant, limit):
    d = tomllib.loads(TINY)
    if kind == "2d":
        d = tomllib.loads((SCENES / "fig02_polaroid.toml").read_text())
    d["grid"]["courant"] = courant
    with pytest.raises(SceneError) as e:
        parse_scene(d, "c.toml").build()
    msg = str(e.value)
    assert "\n" not in msg and "[grid.courant]" in msg and limit in msg and "set courant" in msg


def test_cli_refuses_courant_naming_the_key(tmp_path, capsys):
    f = _tiny(tmp_path, TINY.replace('kind = "3d"\n', 'kind = "3d"\ncourant = 0.6\n', 1))
    assert main(["simulate", str(f), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "[grid.courant]" in err[0]


def test_memory_estimate_refuses_before_building(tmp_path, capsys):
    # an explicit allowance: the estimate plus the runtime exceeds it
    with pytest.raises(SceneTooLargeError, match=r"estimated memory .* Fix: fewer cells"):
        load_scene(_tiny(tmp_path)).build(available_bytes=64 * 2**20)
    # a grid no machine here holds (27 G cells, ~1 TB): refused from the estimate alone, before any
    # grid-sized array exists (building it would exhaust the memory)
    big = TINY.replace("size_m = [0.03, 0.025, 0.02]", "shape = [3000, 3000, 3000]")
    assert main(["simulate", str(_tiny(tmp_path, big)), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "3000 x 3000 x 3000" in err[0] and "estimated memory" in err[0]
    assert not (tmp_path / "out").exists()


def _group_delay_error_periods(cpw: float, courant: float, path_cells: float) -> float:
    """(lattice - continuum) travel time of a wave packet over `path_cells` along a grid axis, in
    periods: the 3-D lattice's group velocity from its dispersion relation (analytic3d)."""
    from difflattice.observe.analytic3d import lattice_wavenumber_3d

    w = 2 * math.pi * courant / cpw  # rad/step
    dw = 1e-4 * w
    dk = float(lattice_wavenumber_3d(w + dw, courant) - lattice_wavenumber_3d(w - dw, courant))
    v_g = 2 * dw / dk
    return path_cells * (1 / v_g - 1 / courant) * w / (2 * math.pi)


def test_cli_runs_a_3d_scene_and_writes_its_outputs(tmp_path, capsys):
    """The wall at normal incidence, 8 cells per wavelength: the A-scan's echo comes back after
    the round trip 2 d / c (d = 25.7 mm, the file's face-to-wall distance, c of air at 20 deg C)
    within one cell of round trip (each of the face and the wall lies within half a cell of its
    position in metres) plus the lattice's group delay over the path."""
    out = tmp_path / "out"
    rc = main(
        [
            "simulate",
            str(SCENES / "wall3d_00deg.toml"),
            "--out",
            str(out),
            "--cells-per-wavelength",
            "8",
            "--assume-mlups",
            "100",
        ]
    )
    assert rc == 0
    captured = capsys.readouterr()
    for name in ("a_scan.csv", "a_scan.json", "peak_slices.png", "field_slices.png", "mip_z.png", "mip_y.png"):
        assert (out / name).stat().st_size > 0, name
    s = json.loads((out / "summary.json").read_text())
    assert s["grid"]["kind"] == "3d" and s["grid"]["cells_per_wavelength"] == 8.0
    assert s["estimate"]["printed"] in captured.err  # printed before the run, kept in the summary
    assert s["run"]["wall_time_s"] > 0 and s["memory"]["host_peak_rss_bytes"] > s["estimate"]["memory_bytes"]
    d = np.loadtxt(out / "a_scan.csv", delimiter=",", skiprows=1)  # one plain header row (pandas reads it)
    assert (out / "a_scan.csv").read_text().splitlines()[0] == "t_s,disc_pa_x_weight"
    assert d.shape == (s["run"]["n_steps"], 2)
    a = d[:, 1]
    gate = s["receivers"]["disc"]["gate_start_step"]
    tx, echo = np.where(np.arange(len(a)) < gate, a, 0.0), np.where(np.arange(len(a)) >= gate, a, 0.0)
    xc = np.correlate(echo, tx, "full")
    k = int(np.argmax(xc))
    frac = 0.5 * (xc[k - 1] - xc[k + 1]) / (xc[k - 1] - 2 * xc[k] + xc[k + 1])
    delay_s = (k + frac - (len(a) - 1)) * s["grid"]["dt_s"]
    c = 331.3 * math.sqrt(1 + 20 / 273.15)
    error_periods = (delay_s - 2 * 0.0257 / c) * 40e3
    cpw, dx = 8.0, s["grid"]["dx_m"]
    tol = 1 / cpw + abs(_group_delay_error_periods(cpw, s["grid"]["courant"], 2 * 0.0257 / dx))
    assert abs(error_periods) < tol, (error_periods, tol)
    assert s["receivers"]["disc"]["echo_peak"] > 0.03 * s["receivers"]["disc"]["transmit_peak"]


def _build_in_a_fresh_process(path: Path, cpw: float | None) -> subprocess.Popen:
    """A fresh interpreter that builds the scene and its stepper, then prints the stepper's kind
    and rank and every difflattice module it imported."""
    code = (
        "import sys, tomllib, warnings\n"
        "warnings.simplefilter('ignore')\n"
        "from difflattice.scene import parse_scene\n"
        "from difflattice.solver.stepper import Stepper\n"
        f"d = tomllib.loads(open({str(path)!r}).read())\n"
        "s = parse_scene(d, 'x')\n"
        f"b = (s.at_resolution({cpw}) if {cpw!r} else s).build()\n"
        "st = Stepper.build(b.grid, b.medium, b.sources, b.sensors, b.edges)\n"
        "print(st.grid.kind, st.init().pressure.ndim)\n"
        "print(' '.join(sorted(m for m in sys.modules if m.startswith('difflattice'))))\n"
    )
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _result(proc: subprocess.Popen) -> tuple[str, set[str]]:
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    stepper, mods = out.strip().splitlines()[-2:]
    return stepper, set(mods.split())


def test_a_2d_scene_builds_nothing_3d_and_a_3d_scene_nothing_2d():
    p2, p3 = (
        _build_in_a_fresh_process(SCENES / "fig02_polaroid.toml", None),
        _build_in_a_fresh_process(SCENES / "wall3d_00deg.toml", 6.0),
    )
    stepper, mods = _result(p2)
    assert stepper == "2d 2"
    assert not [m for m in mods if "3d" in m], mods
    assert "difflattice.solver.estimate" in mods  # every kind's scene is estimated before it is built
    stepper, mods = _result(p3)
    assert stepper == "3d 3"
    two_d = {"difflattice.lattice.geometry", "difflattice.observe.farfield", "difflattice.observe.farfield_rz"}
    assert not two_d & mods, mods


@pytest.mark.parametrize(
    "edit, match",
    [
        (
            lambda d: d["objects"].__setitem__(0, {"shape": "circle", "centre_m": [0.02, 0.01], "radius_m": 0.002}),
            r"objects\[0\]\.shape.*allowed on a 3d grid",
        ),
        (lambda d: d["objects"][0].update(shape="circle"), r"objects\[0\]\.point_m\] is a key of halfspace and slab"),
        (
            lambda d: (
                [d["transducers"][0].pop(k) for k in ("axis", "receive", "gate_start_s") if k in d["transducers"][0]]
                + [d["transducers"][0].update(type="line")]
            ),
            r"transducers\[0\]\.type",
        ),
        (lambda d: d["transducers"][0].update(type="line"), r"transducers\[0\]\.axis\] is a key of disc transducers"),
        (lambda d: d["transducers"][0].update(centre_m=[0.008, 0.0125]), r"transducers\[0\]\.centre_m"),
        (lambda d: d["transducers"][0].update(weights=[1.0, 0.5]), r"transducers\[0\]\.weights.*ring_edges_m"),
        (lambda d: d["transducers"][0].update(baffle="rigid"), r"transducers\[0\]\.baffle"),
        (lambda d: d["grid"].update(size_m=[0.03, 0.025]), r"grid\.size_m.*3 entries"),
        (lambda d: d["edges"].update(r_hi="pml"), r"edges\.r_hi"),
        (lambda d: d["objects"][1].update(centre_m=[0.016, 0.006]), r"objects\[1\]\.centre_m"),
        (lambda d: d["sensors"].update(snapshot_slices_m=[["w", 0.01]]), r"snapshot_slices_m\[0\]"),
        (lambda d: d.update(farfield={}), r"\[farfield\]"),
    ],
)
def test_3d_mismatches_are_refused_naming_the_key(edit, match):
    d = tomllib.loads(TINY)
    edit(d)
    with pytest.raises(SceneError, match=match):
        parse_scene(d, "bad").build()


def test_3d_keys_on_a_2d_scene_are_refused():
    d = tomllib.loads((SCENES / "fig02_polaroid.toml").read_text())
    d["transducers"][0]["axis"] = [1.0, 0.0, 0.0]
    with pytest.raises(SceneError, match=r"transducers\[0\]\.axis\] is a key of disc transducers, not line ones"):
        parse_scene(d, "bad").build()
    # a disc's 3-D key on an rz disc: refused by the build, naming the grid kind
    d = tomllib.loads((SCENES / "disc_piston_rz.toml").read_text())
    d["transducers"][0]["axis"] = [1.0, 0.0, 0.0]
    with pytest.raises(SceneError, match=r"transducers\[0\]\.axis.*3d"):
        parse_scene(d, "bad").build()
