"""A disc fit's report (issue 12): the shipped piston_disc config run by `run_fit` at a coarse
resolution (8 cells per wavelength, the diameter fixed: fast, and the report's content, not the
fit's accuracy, is under test) with `baffle = "none"` writes the disc's field image (the rz
lattice's meridian plane, with the bare disc's housing) and names the model family and the baffle
in report.json and report.md; the baffle reached the transfer. Bad baffle keys are one-line
config errors naming the key."""

import json
import tomllib
from pathlib import Path

import pytest

from difflattice.apps.fitting import run_fit
from difflattice.config import ConfigError
from difflattice.fit.config import config_from_dict

from ._sane import assert_sane_report

ROOT = Path(__file__).resolve().parents[2]


def piston_disc_config(tmp_path: Path, **model):
    raw = tomllib.loads((ROOT / "fitting" / "piston_disc.toml").read_text())
    for k in ("lobe", "wave"):
        raw["data"][k] = str((ROOT / "fitting" / raw["data"][k]).resolve())
    raw["model"].update({"cells_per_wavelength": 8.0, **model})
    raw["uncertainty"] = {"second_cells_per_wavelength": 9.0}
    raw["output"] = {"dir": str(tmp_path / "out"), "field_image": True}
    return config_from_dict(raw)


@pytest.mark.slow  # a whole fit with its error budget: ~15 s on a quiet 2-core machine
def test_rz_disc_fit_report_has_field_image_and_family(tmp_path):
    cfg = piston_disc_config(tmp_path, fit_diameter=False, diameter_m=0.0384, baffle="none")
    rep = run_fit(cfg, out=tmp_path / "out", verbose=False)
    out = tmp_path / "out"
    assert (out / "field.png").is_file() and (out / "field.png").stat().st_size > 10_000
    assert rep["figures"]["field"].endswith("field.png")
    js = json.loads((out / "report.json").read_text())
    assert js["fit"]["model"]["family"] == "disc" and js["fit"]["model"]["baffle"] == "none"
    assert js["transfer"]["baffle"] == "none" and js["transfer"]["face_row"] > 0  # the face inside the window
    md = (out / "report.md").read_text()
    assert "- model: disc family," in md and "rings of" in md and "baffle none" in md
    assert "![field](field.png)" in md
    assert_sane_report(out)  # issue 27: every ring listed, no NaN, no ±0, no unphysical limit


@pytest.mark.parametrize(
    "model, key",
    [
        ({"baffle": "can"}, "model.can_depth_m"),  # a can needs its depth
        ({"baffle": "none", "can_depth_m": 0.01}, "model.can_depth_m"),  # can keys without a can
        ({"baffle": "tube"}, "model.baffle"),  # not a baffle
        ({"baffle": "can", "can_depth_m": -0.01}, "model.can_depth_m"),  # negative depth
    ],
)
def test_rz_bad_baffle_keys_are_config_errors(tmp_path, model, key):
    with pytest.raises(ConfigError, match=rf"\[{key}\]"):
        piston_disc_config(tmp_path, **model)


def test_rz_baffle_is_for_the_disc_model(tmp_path):
    with pytest.raises(ConfigError, match=r"\[model.baffle\].*model = \"disc\" only"):
        piston_disc_config(tmp_path, model="line", weights="uniform", lags="uniform", baffle="none")
