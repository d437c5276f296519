"""Housed-fit configs (fit/housed_config.py) and their route through `difflattice fit`."""

from __future__ import annotations

from pathlib import Path

import pytest

from difflattice.config import ConfigError
from difflattice.fit.housed_config import housed_config_from_dict, is_housed_config, load_housed_config

ROOT = Path(__file__).resolve().parents[2]


def test_shipped_config_loads_and_points_at_a_record_with_a_table():
    cfg = load_housed_config(ROOT / "fitting" / "housed_recessed.toml")
    assert cfg.model.family == "ladder" and cfg.housing.outer_diameter_m == 0.016
    from difflattice.fit.datasheet import load_datasheet

    sheet = load_datasheet(cfg.datasheet_path)
    assert sheet.table is not None and "SYNTHETIC" in sheet.source["document"]
    assert is_housed_config(ROOT / "fitting" / "housed_recessed.toml")
    assert not is_housed_config(ROOT / "fitting" / "piston_disc.toml")


def test_the_real_device_config_reads_its_cited_table():
    """The T4010A1 config: a real datasheet table (cited file and commit), inside the can's outline."""
    from difflattice.fit.datasheet import load_datasheet

    cfg = load_housed_config(ROOT / "fitting" / "housed_t4010a1.toml")
    sheet = load_datasheet(cfg.datasheet_path)
    assert sheet.part == "T4010A1" and "c031b5343ff862c2a03bbe7c5a3e53af44e4d971" in sheet.source["url"]
    assert list(sheet.table["angle_deg"]) == list(range(0, 90, 10)) and sheet.table["sigma_db"] == 0.5
    assert cfg.housing.outer_diameter_m == sheet.outline["outer_diameter_m"] == 0.010


def test_flanged_front_is_read():
    raw = {
        "data": {"datasheet": "x.toml"},
        "model": {"model": "housed", "housing": {"outer_diameter_m": 0.01, "length_m": 0.01, "front": "flange"}},
    }
    assert housed_config_from_dict(raw).housing.front == "flange"
    raw["model"]["housing"].pop("front")
    assert housed_config_from_dict(raw).housing.front == "free"


@pytest.mark.parametrize(
    ("raw", "match"),
    [
        ({"data": {"datasheet": "x.toml"}, "model": {"model": "housed"}}, "model.housing"),
        (
            {"data": {"datasheet": "x.toml"}, "model": {"model": "housed", "housing": {"length_m": 0.01}}},
            "outer_diameter_m",
        ),
        (
            {
                "data": {"datasheet": "x.toml"},
                "model": {"model": "housed", "family": "horn", "housing": {"outer_diameter_m": 0.01, "length_m": 0.01}},
            },
            "family",
        ),
        (
            {
                "data": {"datasheet": "x.toml"},
                "model": {"model": "housed", "housing": {"outer_diameter_m": 0.01, "length_m": 0.01, "wall_m": 0.006}},
            },
            "no bore",
        ),
        (
            {
                "data": {"datasheet": "x.toml"},
                "model": {"model": "housed", "housing": {"outer_diameter_m": 0.01, "length_m": 0.01, "front": "wall"}},
            },
            "front",
        ),
        (
            {
                "data": {"datasheet": "x.toml"},
                "model": {
                    "model": "housed",
                    "housing": {"outer_diameter_m": 0.01, "length_m": 0.01, "front": "flange", "back": "open"},
                },
            },
            "needs back",
        ),
    ],
)
def test_bad_configs_name_the_key(raw, match):
    with pytest.raises(ConfigError, match=match):
        housed_config_from_dict(raw, path="cfg.toml")


def test_difflattice_fit_routes_a_housed_config_and_refuses_a_record_without_a_table(tmp_path):
    """A real device's record (a stated beam angle only) is refused before any simulation, with
    the fix: digitise its directivity figure."""
    from difflattice.apps.fitting import run_fit_config

    record = ROOT / "data" / "datasheets" / "prowave_400pt120.toml"
    cfg = tmp_path / "housed.toml"
    cfg.write_text(
        f'[data]\ndatasheet = "{record}"\n[model]\nmodel = "housed"\n'
        "[model.housing]\nouter_diameter_m = 0.016\nlength_m = 0.012\n"
    )
    with pytest.raises(ValueError, match="digitise"):
        run_fit_config(cfg, out=tmp_path / "out")


def test_synthetic_record_is_reproduced_by_its_script(tmp_path):
    """data/emulated/housed_recessed/record.toml is what fitting/housed_recessed_reference.py writes."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("ref", ROOT / "fitting" / "housed_recessed_reference.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = mod.run(out=tmp_path / "record.toml")
    assert out.read_text() == (ROOT / "data" / "emulated" / "housed_recessed" / "record.toml").read_text()


SHIPPED = sorted((ROOT / "fitting").glob("housed_*.toml"))


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_every_shipped_housed_config_loads_with_its_record(path):
    """Each fitting/housed_*.toml is a housed config whose record has a digitised table, and the
    can it models is the one its record states (where the record states an outline)."""
    from difflattice.fit.datasheet import load_datasheet

    assert is_housed_config(path)
    cfg = load_housed_config(path)
    sheet = load_datasheet(cfg.datasheet_path)
    assert sheet.table is not None and len(sheet.lobe().angle_deg) >= 3
    h = cfg.housing
    for key, value in (("outer_diameter_m", h.outer_diameter_m), ("length_m", h.length_m)):
        if key in sheet.outline:
            assert value == sheet.outline[key], (path.name, key, value, sheet.outline[key])


def test_the_weak_provenance_record_says_so():
    """The MA40S4S table's sources cite no datasheet figure: its record says so where a reader looks."""
    from difflattice.fit.datasheet import load_datasheet

    sheet = load_datasheet(ROOT / "data" / "datasheets" / "murata_ma40s4s.toml")
    assert sheet.notes.startswith("WEAK PROVENANCE") and "NOT cited" in sheet.source["document"]
    assert list(sheet.table["angle_deg"]) == list(range(0, 91, 2)) and sheet.table["level_db"][-1] == -20.0


def test_lobe_mask_leaves_angles_out_and_is_checked(tmp_path):
    """`[data] lobe_mask_deg` (as the ordinary fit configs): the record's angles in the closed
    ranges are not fitted; a mask that leaves < 3 points is an error, one that leaves out nothing
    a warning."""
    import warnings

    from difflattice.config import ConfigWarning
    from difflattice.fit.datasheet import load_datasheet
    from difflattice.fit.housed_config import housed_lobe

    record = ROOT / "data" / "datasheets" / "murata_ma40s4s.toml"
    sheet = load_datasheet(record)

    def cfg(mask):
        raw = {
            "data": {"datasheet": str(record), "lobe_mask_deg": mask},
            "model": {"model": "housed", "housing": {"outer_diameter_m": 0.0099, "length_m": 0.0071}},
        }
        return housed_config_from_dict(raw, path=tmp_path / "c.toml")

    lobe, notes = housed_lobe(cfg([[60, 90]]), sheet)
    assert list(lobe.angle_deg) == list(range(0, 60, 2)) and "left out 16 of 46" in notes[0]
    assert housed_lobe(cfg([]), sheet)[0].angle_deg.size == 46
    with pytest.raises(ConfigError, match=r"\[data.lobe_mask_deg\] .* leaves 2 of 46"):
        housed_lobe(cfg([[4, 90]]), sheet)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ConfigWarning, match="excludes no angle"):
            housed_lobe(cfg([[91, 100]]), sheet)


def test_report_names_the_families_that_did_not_converge():
    """report.md says which families stopped at the iteration limit (their rows are not minima)."""
    from types import SimpleNamespace

    from difflattice.apps.fitting_housed import _not_converged_line

    ok, stuck = SimpleNamespace(converged=True), SimpleNamespace(converged=False)
    line = _not_converged_line(SimpleNamespace(fits={"flat": ok, "opening": stuck, "profile": stuck}))
    assert "Not converged" in line and line.strip().endswith("opening, profile.") and "flat" not in line
    assert _not_converged_line(SimpleNamespace(fits={"flat": ok})) == ""
