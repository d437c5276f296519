"""The command line and the main job end to end (small settings)."""

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from difflattice.apps.fitting import run_fit
from difflattice.cli import main
from difflattice.fit.config import load_config

ROOT = Path(__file__).resolve().parents[1]

SMALL_SCENE = """
[grid]
frequency_hz = 50000.0
cells_per_wavelength = 10.0
shape = [120, 100]
[[transducers]]
centre_m = [0.02, 0.034]
n_cells = 20
cycles = 3
[[objects]]
shape = "segment"
a_m = [0.03, 0.048]
b_m = [0.045, 0.048]
thickness_m = 0.002
material = "rigid"
[sensors]
probes_m = [[0.03, 0.034]]
snapshot_every_steps = 100
[farfield]
range_m = 1.0
angles_deg = [-60.0, 60.0, 1.0]
[run]
n_steps = 300
"""


def test_simulate_writes_outputs(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text(SMALL_SCENE)
    assert main(["simulate", str(scene), "--out", str(tmp_path / "out"), "--quiet", "--no-animation"]) == 0
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert s["stability"]["finite"]
    assert s["run"]["n_steps"] == 300
    assert 0 < s["accuracy"]["expected_phase_error_rad"] < math.pi
    assert s["farfield"]["width_6db_deg"] > 0
    for f in ("field.png", "peak_level.png", "lobe.png", "probes.png", "sensors.npz"):
        assert (tmp_path / "out" / f).exists()
    assert len(list((tmp_path / "out" / "frames").glob("*.png"))) == 3


@pytest.mark.parametrize(
    "patch, message",
    [
        (("n_cells = 20", "n_cells = 20\ncolour = 3"), "transducers[0].colour] unknown key; allowed:"),
        (
            ("cells_per_wavelength = 10.0", "cells_per_wavelength = 'ten'"),
            "grid.cells_per_wavelength] must be a number",
        ),
        (('material = "rigid"', 'material = "cheese"'), "objects[0].material] unknown material 'cheese'; known:"),
        (("shape = [120, 100]", "shape = [120, 100]\ncourant = 0.75"), "exceeds the 2-D stability limit"),
        (("centre_m = [0.02, 0.034]", "centre_m = [0.001, 0.034]"), "absorbing layer"),
    ],
)
def test_bad_scene_files_name_file_and_key(tmp_path, capsys, patch, message):
    scene = tmp_path / "bad.toml"
    scene.write_text(SMALL_SCENE.replace(*patch))
    code = main(["simulate", str(scene), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert str(scene) in err and message in err, err


def test_fit_config_is_reproducible(tmp_path, monkeypatch):
    """Two runs of a config agree to round-off: the first with the error budget's second-resolution
    transfer simulated in a background thread beside the fit (once, and used by the budget), the
    second with it simulated when the budget asks (no prefetch)."""
    import threading

    import difflattice.apps.fitting as fc
    import difflattice.fit.transfer as ft

    calls = []
    real = ft.free_field_transfer
    monkeypatch.setattr(
        ft,
        "free_field_transfer",
        lambda **k: calls.append((k["cells_per_wavelength"], threading.current_thread().name)) or real(**k),
    )
    cfg = load_config(ROOT / "fitting" / "polaroid_like.toml")
    a = run_fit(cfg, out=tmp_path / "a", quick=True, verbose=False)
    assert [c for c, _ in calls] == [12.0, 18.0], calls  # quick: 12 cells/wavelength, the budget's at 1.5x
    assert calls[1][1].startswith("difflattice-prefetch"), calls
    assert a["budget"]["resolution"]["measured"]
    calls.clear()
    monkeypatch.setattr(fc, "_Prefetched", lambda make, cpw: make)
    b = run_fit(cfg, out=tmp_path / "b", quick=True, verbose=False)
    assert [c for c, _ in calls] == [12.0, 18.0] and calls[1][1] == threading.current_thread().name, calls
    pa, pb = a["fit"]["parameters"], b["fit"]["parameters"]
    assert a["fit"]["converged"]
    # deterministic pipeline: identical to round-off
    assert abs(pa["diameter_m"] - pb["diameter_m"]) < 1e-12
    assert max(abs(x - y) for x, y in zip(pa["lags_s"], pb["lags_s"])) < 1e-15
    assert len(a["budget"]["scalars"]) == len(b["budget"]["scalars"]) > 0
    for sa, sb in zip(a["budget"]["scalars"], b["budget"]["scalars"]):
        assert sa["name"] == sb["name"] and (sa["total"] == sb["total"] or abs(sa["total"] - sb["total"]) < 1e-12)
    prov = a["provenance"]
    assert len(prov["config_sha256"]) == 64 and all(len(h) == 64 for h in prov["data_sha256"].values())
    assert "jax" in prov["versions"]


def test_the_command_ends_with_its_exit_code_and_all_its_output(tmp_path):
    """`python -m difflattice.cli` ends with `os._exit` after `main` (no slow interpreter
    shutdown): the exit code and what was printed still arrive. Here a config error: code 2 and
    the `error:` line naming the missing file (`test_demo_quick` runs a whole job this way)."""
    bad = tmp_path / "bad.toml"
    bad.write_text((ROOT / "fitting" / "polaroid_like.toml").read_text().replace("lobe.csv", "no_such_lobe.csv"))
    r = subprocess.run(
        [sys.executable, "-m", "difflattice.cli", "fit", str(bad)], capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    assert "error:" in r.stderr and "no_such_lobe.csv" in r.stderr, r.stderr[-2000:]


def test_demo_quick(tmp_path):
    """The main job on a coarse setting: emulator process, pseudo-terminal capture, fit, report."""
    out = tmp_path / "demo"
    r = subprocess.run(
        [sys.executable, "-m", "difflattice.cli", "demo", "--quick", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    rep = json.loads((out / "report" / "report.json").read_text())
    assert rep["fit"]["converged"]
    assert (out / "report" / "report.md").exists() and (out / "report" / "lobe.png").exists()
    summ = json.loads((out / "demo_summary.json").read_text())
    assert summ["recovery"]["diameter_m"]["fitted"] == pytest.approx(summ["recovery"]["diameter_m"]["true"], abs=1e-3)
