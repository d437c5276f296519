"""Every impossible fit config is refused by `difflattice fit` with exit code 2 and ONE line on
stderr naming the key (no traceback); legal but unwise values warn; values that used to be
ignored or silently changed are now used as given.

The cases run the real command in-process (`difflattice.cli.main`); they fail before any
simulation, so the matrix is fast. One case runs in a subprocess to check the console entry point.
"""

from __future__ import annotations

import math
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from difflattice.capture.files import CaptureWriter
from difflattice.cli import main
from difflattice.config import ConfigError, ConfigWarning
from difflattice.fit.config import load_config
from difflattice.fit.loading import load_fit_data

ROOT = Path(__file__).resolve().parents[2]
LOBE = ROOT / "data" / "emulated" / "lobe_piston38_40k.csv"  # 40 kHz
WAVE = ROOT / "data" / "emulated" / "wave_piston38_40k_z16.5mm.csv"  # 40 kHz
WAVE_50K = ROOT / "data" / "emulated" / "polaroid_like" / "wave.csv"  # 50 kHz

BASE = {
    "data": {"lobe": f'"{LOBE}"'},
    "model": {"line_length_m": "0.042", "lobe_range_m": "1000.0", "weights": '"smooth"', "lags": '"uniform"'},
    "solver": {"floor_db": "40.0"},
}

HEADER = {
    "kind": "lobe",
    "created_utc": "2026-01-01T00:00:00.000Z",
    "protocol": 1,
    "rig_id": "EMU-0001",
    "fw_version": "0.3.1-emu",
    "boot_id": 1,
    "scan_id": 7,
    "n_points": 5,
    "start_mdeg": -2000,
    "step_mdeg": 1000,
    "n_avg": 8,
    "cycles": 16,
    "freq_hz": 40000,
    "range_m": 1.0,
    "temperature_c": 21.0,
    "speed_of_sound_m_s": 343.8,
}
WAVE_HEADER = {
    **{k: v for k, v in HEADER.items() if k not in ("start_mdeg", "step_mdeg", "range_m")},
    "kind": "wave",
    "x0_um": -2000,
    "dx_um": 1000,
    "z_um": 16500,
}


def toml(sections: dict[str, dict[str, str]]) -> str:
    return "".join(f"[{s}]\n" + "".join(f"{k} = {v}\n" for k, v in keys.items()) + "\n" for s, keys in sections.items())


def patched(**changes: dict[str, str | None]) -> str:
    """BASE with keys changed (None: removed); a section given as {"": None} is removed."""
    out = {s: dict(v) for s, v in BASE.items()}
    for section, keys in changes.items():
        if keys == {"": None}:
            out.pop(section, None)
            continue
        out.setdefault(section, {})
        for k, v in keys.items():
            if v is None:
                out[section].pop(k, None)
            else:
                out[section][k] = v
    return toml(out)


def lobe_capture(path: Path, seqs: list[int]) -> Path:
    with CaptureWriter.create(path, HEADER) as w:
        for s in seqs:
            w.append((s, -2000 + 1000 * s, 40000 + 100 * s, 300, 2906203, 2100), 1.0)
    return path


def old_wave_capture(path: Path) -> Path:
    """A wavefront file as the emulator wrote them before 2026-11-23: -arg p in [-180, 180) deg."""
    with CaptureWriter.create(path, {**WAVE_HEADER, "n_points": 5}) as w:
        for s in range(5):
            w.append((s, -2000 + 1000 * s, 16500, 48000, -90000 + 1000 * s, 60000, 2100), 1.0)
        w.finish()
    return path


def table(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def plain(t: Path, extra_row: str = "") -> str:
    """A plain table file in `t` (the PLAIN rows plus `extra_row`), quoted for TOML."""
    return f'"{table(t / "p.csv", PLAIN + extra_row)}"'


PLAIN = "angle_deg,level_db\n" + "".join(f"{a},{-abs(a) / 3:.2f}\n" for a in range(-60, 61, 5))

# (id, config text or a function of tmp_path returning it, the key the one-line error must name)
CASES = [
    ("cells_per_wavelength=1", patched(model={"cells_per_wavelength": "1"}), "[model.cells_per_wavelength]"),
    ("cells_per_wavelength=0", patched(model={"cells_per_wavelength": "0"}), "[model.cells_per_wavelength]"),
    ("cells_per_wavelength=string", patched(model={"cells_per_wavelength": '"20"'}), "[model.cells_per_wavelength]"),
    ("cells_per_wavelength=nan", patched(model={"cells_per_wavelength": "nan"}), "[model.cells_per_wavelength]"),
    ("floor_db=-10", patched(solver={"floor_db": "-10"}), "[solver.floor_db]"),
    ("floor_db=nan", patched(solver={"floor_db": "nan"}), "[solver.floor_db]"),
    ("lobe_range_m=-1", patched(model={"lobe_range_m": "-1"}), "[model.lobe_range_m]"),
    ("negative diameter, fixed", patched(model={"diameter_m": "-0.03", "fit_diameter": "false"}), "[model.diameter_m]"),
    ("diameter > line", patched(model={"diameter_m": "0.05"}), "[model.diameter_m]"),
    ("diameter = line, fitted", patched(model={"diameter_m": "0.042", "fit_diameter": "true"}), "[model.diameter_m]"),
    ("wave_sigma_deg=-1", patched(solver={"wave_sigma_deg": "-1"}), "[solver.wave_sigma_deg]"),
    (
        "wave_sigma_deg below the rig's resolution",
        patched(solver={"wave_sigma_deg": "0.0001"}),
        "[solver.wave_sigma_deg]",
    ),
    ("line_length_m<0", patched(model={"line_length_m": "-0.04"}), "[model.line_length_m]"),
    ("line_length_m=inf", patched(model={"line_length_m": "inf"}), "[model.line_length_m]"),
    (
        "line shorter than 3 cells",
        patched(model={"line_length_m": "1e-4", "diameter_m": None}),
        "[model.line_length_m]",
    ),
    ("line_length_m missing", patched(model={"line_length_m": None}), "[model.line_length_m]"),
    ("no [model]", patched(model={"": None}), "[model]"),
    ("data file missing", patched(data={"lobe": '"no_such_file.csv"'}), "[data.lobe]"),
    ("data path is a folder", patched(data={"lobe": f'"{ROOT / "data"}"'}), "[data.lobe]"),
    ("wave file given as lobe", patched(data={"lobe": f'"{WAVE}"'}), "[data.lobe]"),
    ("lobe file given as wave", patched(data={"lobe": None, "wave": f'"{LOBE}"'}), "[data.wave]"),
    ("no data", patched(data={"lobe": None}), "[data]"),
    ("unknown key", patched(model={"colour": '"red"'}), "[model.colour]"),
    ("misspelt key", patched(model={"cell_per_wavelength": "20"}), "[model.cell_per_wavelength]"),
    ("unknown section", patched(plots={"dpi": "100"}), "[plots]"),
    ("fit_diameter=string", patched(model={"fit_diameter": '"yes"'}), "[model.fit_diameter]"),
    ("max_steps=2.5", patched(solver={"max_steps": "2.5"}), "[solver.max_steps]"),
    ("max_steps=0", patched(solver={"max_steps": "0"}), "[solver.max_steps]"),
    ("n_basis=true", patched(model={"n_basis": "true"}), "[model.n_basis]"),
    ("lobe_weight=-inf", patched(solver={"lobe_weight": "-inf"}), "[solver.lobe_weight]"),
    ("nothing weighted", patched(solver={"lobe_weight": "0"}), "[solver]"),
    ("solver name", patched(solver={"name": '"newton"'}), "[solver.name]"),
    ("loss", patched(solver={"loss": '"l1"'}), "[solver.loss]"),
    ("weights family", patched(model={"weights": '"gaussian"'}), "[model.weights]"),
    ("disc-only profile on a line", patched(model={"weights": '"rim_taper"'}), "[model.weights]"),
    ("disc-only stencil on a line", patched(model={"stencil": '"isotropic"'}), "[model.stencil]"),
    ("unknown stencil", patched(model={"stencil": '"nine_point"'}), "[model.stencil]"),
    ("model family", patched(model={"model": '"cone"'}), "[model.model]"),
    (
        "second resolution equal",
        patched(uncertainty={"second_cells_per_wavelength": "20.0"}),
        "[uncertainty.second_cells_per_wavelength]",
    ),
    (
        "model family list",
        patched(uncertainty={"model_families": '["smooth", "spline"]'}),
        "[uncertainty.model_families]",
    ),
    ("lobe mask reversed", patched(data={"lobe_mask_deg": "[[60, -60]]"}), "[data.lobe_mask_deg]"),
    ("lobe mask leaves < 3", patched(data={"lobe_mask_deg": "[[-90, 90]]"}), "[data.lobe_mask_deg]"),
    ("wave mask without wave", patched(data={"wave_mask_m": "[[-0.01, 0.01]]"}), "[data.wave_mask_m]"),
    ("frequency mismatch with the file", patched(data={"frequency_hz": "41000"}), "[data.frequency_hz]"),
    ("range mismatch with the file", patched(data={"range_m": "2.0"}), "[data.range_m]"),
    ("lobe and wave at different frequencies", patched(data={"wave": f'"{WAVE_50K}"'}), "[data]"),
    ("empty capture", lambda t: patched(data={"lobe": f'"{lobe_capture(t / "e.csv", [])}"'}), "[data.lobe]"),
    (
        "capture of 2 points",
        lambda t: patched(data={"lobe": f'"{lobe_capture(t / "two.csv", [0, 3])}"'}),
        "[data.lobe]",
    ),
    (
        "old-convention wave file",
        lambda t: patched(data={"lobe": None, "wave": f'"{old_wave_capture(t / "w.csv")}"'}),
        "[data.wave]",
    ),
    ("plain table without metadata", lambda t: patched(data={"lobe": plain(t)}), "[data.frequency_hz]"),
    (
        "plain table without sigma",
        lambda t: patched(data={"lobe": plain(t), "frequency_hz": "40000", "range_m": "1.0", "temperature_c": "20"}),
        "[data.lobe_sigma_db]",
    ),
    ("plain table as wave", lambda t: patched(data={"lobe": None, "wave": plain(t)}), "[data.wave]"),
    ("malformed plain table", lambda t: patched(data={"lobe": plain(t, "70,-20,3\n")}), "[data.lobe]"),
    ("plain table with text", lambda t: patched(data={"lobe": plain(t, "75,n/a\n")}), "[data.lobe]"),
    ("plain table with a NaN", lambda t: patched(data={"lobe": plain(t, "75,nan\n")}), "[data.lobe]"),
    ("not TOML", "[model\nline_length_m = 0.04\n", "not valid TOML"),
]


@pytest.mark.parametrize("text, key", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_config_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], text, key: str) -> None:
    cfg = tmp_path / "fit.toml"
    cfg.write_text(text(tmp_path) if callable(text) else text)
    code = main(["fit", str(cfg), "--quick", "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code == 2, (out, err)
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ") and key in lines[0] and str(cfg) in lines[0], lines[0]
    assert "Traceback" not in out + err
    assert not (tmp_path / "out").exists()  # nothing was run


def test_missing_config_file(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code = main(["fit", str(tmp_path / "nope.toml")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "nope.toml" in err[0] and "cannot read" in err[0]


def test_console_entry_point_prints_one_line(tmp_path: Path) -> None:
    """The installed command path (a fresh process): one line, exit 2, no traceback."""
    cfg = tmp_path / "fit.toml"
    cfg.write_text(patched(model={"cells_per_wavelength": "0"}))
    r = subprocess.run(
        [sys.executable, "-m", "difflattice.cli", "fit", str(cfg)], capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().count("\n") == 0 and "[model.cells_per_wavelength] = 0 is out of range" in r.stderr
    assert "allowed: 4 <= x <= 200" in r.stderr and "fix:" in r.stderr and "Traceback" not in r.stderr


def test_error_names_value_range_and_fix(tmp_path: Path) -> None:
    cfg = tmp_path / "fit.toml"
    cfg.write_text(patched(solver={"floor_db": "-10"}))
    with pytest.raises(ConfigError) as e:
        load_config(cfg)
    msg = str(e.value)
    assert msg == (
        f"{cfg}: [solver.floor_db] = -10 is out of range; allowed: 0 < x <= 200 dB; "
        "fix: use a few dB less than the data's dynamic range, e.g. 40"
    )


# -- warnings: legal but unwise ---------------------------------------------------------------


def test_coarse_resolution_warns(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "fit.toml"
    cfg.write_text(patched(model={"cells_per_wavelength": "6"}))
    with pytest.warns(ConfigWarning, match=r"\[model.cells_per_wavelength\] = 6 cells per wavelength is coarse"):
        load_config(cfg)
    # on the console: one "warning:" line, then (here) the error of a missing file
    cfg.write_text(patched(model={"cells_per_wavelength": "6"}, data={"lobe": '"missing.csv"'}))
    assert main(["fit", str(cfg)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith("warning: ") and "cells_per_wavelength" in err[0], err
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cfg.write_text(patched(model={"cells_per_wavelength": "8"}))
        load_config(cfg)  # 8 is fine


def test_floor_below_the_datas_dynamic_range_warns(tmp_path: Path) -> None:
    """A digitised datasheet pattern clipped at -30 dB (its plot's axis) with the floor at 40 dB
    below the peak: the clipped nulls would be fitted at face value."""
    rows = "".join(f"{a},{max(-abs(a) * 0.8, -30):.2f}\n" for a in range(-90, 91, 2))
    plain = table(tmp_path / "datasheet.csv", "angle_deg,level_db\n" + rows)
    cfg = tmp_path / "fit.toml"
    extra = {
        "lobe": f'"{plain}"',
        "frequency_hz": "40000",
        "range_m": "1.0",
        "temperature_c": "20",
        "lobe_sigma_db": "0.5",
    }
    cfg.write_text(patched(data=extra))
    with pytest.warns(
        ConfigWarning, match=r"\[solver.floor_db\] = 40 dB reaches below the data's dynamic range \(30.0 dB"
    ):
        load_fit_data(load_config(cfg))
    cfg.write_text(patched(data=extra, solver={"floor_db": "25"}))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_fit_data(load_config(cfg))


# -- values that used to be ignored or changed are used as given -------------------------------


def test_small_wave_sigma_is_respected(tmp_path: Path) -> None:
    """fitting/polaroid_like.toml gives 0.1 deg (0.3 deg per burst / sqrt(8)); it was silently
    raised to 0.5 deg."""
    cfg = load_config(ROOT / "fitting" / "polaroid_like.toml")
    assert cfg.solver.wave_sigma_deg == 0.1
    wave = load_fit_data(cfg).wave
    assert wave.sigma_rad == pytest.approx(math.radians(0.1))


def test_given_diameter_starts_a_fitted_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With fit_diameter = true a given diameter_m is the initial value (it used to be ignored:
    the diameter scan always ran)."""
    import difflattice.fit.solve as solve

    seen = {}

    class Stop(Exception):
        pass

    def fake_fit(spec, transfer, lobe, wave, options, *, params0=None, progress=False, multistart=False, solve_in=None):
        seen["params0"], seen["spec"], seen["multistart"] = params0, spec, multistart
        raise Stop

    monkeypatch.setattr(solve, "fit", fake_fit)
    cfg = tmp_path / "fit.toml"
    cfg.write_text(patched(model={"diameter_m": "0.036", "fit_diameter": "true", "cells_per_wavelength": "8"}))
    with pytest.raises(Stop):
        from difflattice.apps.fitting import run_fit

        run_fit(load_config(cfg), out=tmp_path / "o", verbose=False)
    spec, p0 = seen["spec"], seen["params0"]
    assert p0 is not None and p0.has("diam")
    assert float(spec.physical(p0)["diameter_m"]) == pytest.approx(0.036, rel=1e-9)
    assert seen["multistart"]  # issue 27: the given start is one of two (the scan's best is the other)


# -- one declaration, everything generated from it ----------------------------------------------


def test_solver_defaults_are_the_solvers() -> None:
    """[solver] keys that FitOptions also has default to the same values (no second table that
    could drift)."""
    import dataclasses

    from difflattice.config import specs
    from difflattice.fit.config import SolverSection
    from difflattice.fit.solve import FitOptions

    ours = {s.name: s.default for s in specs(SolverSection)}
    theirs = {f.name: f.default for f in dataclasses.fields(FitOptions)}
    renamed = {"name": "solver"}
    shared = [k for k in ours if renamed.get(k, k) in theirs]
    assert {"loss", "loss_scale", "rtol_cost", "rtol_step", "floor_db", "max_steps"} <= set(shared)
    for k in shared:
        assert ours[k] == theirs[renamed.get(k, k)], k


def test_docs_tables_are_generated_from_the_declarations() -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("gen_config_tables", ROOT / "docs" / "gen_config_tables.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--check"]) == 0
    page = (ROOT / "docs" / "fitting.md").read_text()
    assert "| `wave_sigma_deg` | number | `1` | deg | 0.001 <= x <= 90 |" in page


def test_every_cli_option_shows_its_default() -> None:
    """`--help` of every subcommand states each option's default (or that it is required)."""
    import argparse

    from difflattice.cli import build_parser

    def walk(p):
        yield p
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub in dict.fromkeys(a.choices.values()):
                    yield from walk(sub)

    missing = []
    for p in walk(build_parser()):
        fmt = p._get_formatter()
        for a in p._actions:
            flag = isinstance(
                a,
                (argparse._HelpAction, argparse._VersionAction, argparse._StoreTrueAction, argparse._StoreFalseAction),
            )
            if not a.option_strings or a.required or flag or a.help == argparse.SUPPRESS:
                continue
            text = fmt._expand_help(a) if a.help else ""
            if "default" not in text and "required" not in text:
                missing.append(f"{p.prog} {a.option_strings[0]}")
    assert not missing, missing
