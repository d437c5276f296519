"""Fit reports: every fitted parameter with statistical, systematic and total uncertainty in
report.md; model curves, null angles, side lobes and beam widths in report.json (the beam metrics
checked against the analytic pattern of a uniform line); plots without pyplot, a field image with
a colour bar, a polar lobe with labelled rings and a legend."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from difflattice import plots
from difflattice.fit.report import beam_metrics, write_report
from difflattice.fit.solve import FitOptions, fit

from ._emulated import data, spec, transfer
from ._sane import assert_sane_report


def test_beam_metrics_of_a_uniform_line():
    """A uniform line of length L in the far field: |sinc(L sin(theta) / lambda)|, nulls at
    sin(theta) = m lambda / L, -3 dB full width 2 asin(0.4429 lambda / L), first side lobe -13.26 dB."""
    lam, L = 1.0, 4.3
    a = np.arange(-90, 90.0001, 0.05)
    lv = 20 * np.log10(np.abs(np.sinc(L * np.sin(np.radians(a)) / lam)) + 1e-12)
    m = beam_metrics(a, lv)
    nulls = np.degrees(np.arcsin(np.arange(1, int(L / lam) + 1) * lam / L))
    np.testing.assert_allclose(sorted(x for x in m["null_angles_deg"] if x > 0), nulls, atol=0.05)
    assert len(m["null_angles_deg"]) == 2 * len(nulls)
    assert abs(m["width_3db_deg"] - 2 * math.degrees(math.asin(0.4429 * lam / L))) < 0.05
    assert abs(m["highest_side_lobe_db"] - (-13.26)) < 0.05
    assert len(m["side_lobes"]) == 2 * len(nulls)  # one between each pair of nulls, one beyond the last


def test_report_lists_every_parameter_and_the_curves(tmp_path):
    T = transfer(12.0)
    lobe, wave, truth = data(T)
    r = fit(spec(T), T, lobe, wave, FitOptions())
    rep = write_report(tmp_path, r, None, T, lobe, wave, provenance={}, field_image=False, truth=truth)
    md = (tmp_path / "report.md").read_text()
    js = json.loads((tmp_path / "report.json").read_text())
    # every fitted parameter, with statistical, systematic and total columns
    assert "| parameter | value | statistical | systematic | total |" in md
    for lab in r.raw_labels:
        name = {"diameter.logit": "diameter_mm", "gain_db": "gain_db", "phase0_rad": "phase0_deg"}.get(lab, lab)
        assert f"| {name} (" in md, name
    assert "systematic parts not measured" in md  # no budget given: said so
    # model curves and beam metrics
    c = js["model_curves"]
    assert len(c["lobe"]["model_db"]) == len(lobe.angle_deg) and len(c["wavefront"]["model_phase_deg"]) == len(wave.x_m)
    b = js["beam"]["fitted model"]
    assert b["width_3db_deg"] > 0 and b["width_6db_deg"] > b["width_3db_deg"]
    assert b["null_angles_deg"] and b["side_lobes"] and b["highest_side_lobe_db"] < 0
    assert js["trace"]["stages"] and len(js["trace"]["cost"]) == r.n_steps
    assert len(js["aperture"]["weights_re_centre"]) == T.n_cells
    for f in ("lobe", "wavefront", "aperture", "convergence"):
        assert (tmp_path / f"{f}.png").exists()
    assert rep["fit"]["convergence"]["converged"]
    assert_sane_report(tmp_path)  # issue 27: no NaN, no ±0, every cell listed


def test_plots_without_pyplot_colour_bar_and_polar_labels():
    code = "import difflattice.plots, sys; print('matplotlib.pyplot' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "False"  # importing plots chooses no backend and loads no pyplot
    fig = plots.field_image(np.random.default_rng(0).normal(size=(40, 30)), 1e-3, step=5, dt_s=1e-6)
    assert len(fig.axes) == 2 and "pressure (Pa)" in fig.axes[1].get_ylabel()
    a = np.arange(-90, 91, 2.0)
    fig = plots.lobe_plots(a, {"measured": (-np.abs(a) / 3, "o"), "model": -np.abs(a) / 3})
    polar = fig.axes[0]
    assert polar.get_legend() is not None
    assert {"-10 dB", "-20 dB", "0 dB"} <= {t.get_text() for t in polar.texts}


def test_figures_drawn_in_the_worker_process_equal_those_drawn_here(tmp_path, monkeypatch):
    """`start_figures` (as `run_fit` calls it, before the error budget) draws the figures in a
    worker process: the same files, byte for byte, as drawn in this process (matplotlib's Agg
    output is deterministic); a worker's failure is raised with its error."""
    from difflattice.fit.report import FigureWriter, start_figures

    T = transfer(12.0)
    lobe, wave, _ = data(T)
    r = fit(spec(T), T, lobe, wave, FitOptions())
    names = ("lobe", "wavefront", "convergence", "field")
    a = start_figures(tmp_path / "worker", r, None, T, lobe, wave, background=True)
    assert a._proc is not None, "no worker process started on this machine"
    got = a.results()
    b = start_figures(tmp_path / "here", r, None, T, lobe, wave, background=False).results()
    assert sorted(got) == sorted(b) == sorted(names)
    for n in names:
        assert got[n].read_bytes() == b[n].read_bytes(), n
    # a failing job is reported with the worker's error, not lost
    w = FigureWriter(background=True)
    w.submit("bad", "lobe_plots", tmp_path / "bad.png", np.zeros(3), {"x": np.zeros(4)})
    with pytest.raises(RuntimeError, match="figure worker failed"):
        w.results()
