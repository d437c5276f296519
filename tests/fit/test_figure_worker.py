"""The report's figure worker started ahead (`figures.prestart_worker`, issue 30: its matplotlib
import runs beside the fit): the next writer takes that process and draws with it; a spare that
died is not taken; one never taken exits when its input ends."""

from __future__ import annotations

import numpy as np
import pytest

from difflattice.fit import figures


@pytest.fixture(autouse=True)
def _no_spare():
    yield
    while figures._SPARE:
        proc, err = figures._SPARE.pop()
        proc.kill()
        proc.wait()
        err.close()


def _job(w: figures.FigureWriter, path):
    a = np.arange(-90, 91, 10.0)
    w.submit("lobe", "lobe_plots", path, a, {"measured": (-np.abs(a) / 3, "o")})


def test_the_next_writer_takes_the_started_worker(tmp_path):
    figures.prestart_worker()
    if not figures._SPARE:
        pytest.skip("no worker process on this machine (one CPU, or DIFFLATTICE_REPORT_WORKER=0)")
    proc = figures._SPARE[0][0]
    figures.prestart_worker()  # a second call keeps the one started
    assert [p for p, _ in figures._SPARE] == [proc]
    w = figures.FigureWriter(background=True)
    assert w._proc is proc and not figures._SPARE
    _job(w, tmp_path / "lobe.png")
    got = w.results()
    assert got["lobe"].stat().st_size > 1000 and proc.returncode == 0


def test_a_dead_spare_is_not_taken(tmp_path):
    figures.prestart_worker()
    if not figures._SPARE:
        pytest.skip("no worker process on this machine")
    dead = figures._SPARE[0][0]
    dead.kill()
    dead.wait()
    w = figures.FigureWriter(background=True)
    assert w._proc is not None and w._proc is not dead
    _job(w, tmp_path / "lobe.png")
    assert w.results()["lobe"].exists()


def test_a_spare_never_taken_exits_when_its_input_ends():
    figures.prestart_worker()
    if not figures._SPARE:
        pytest.skip("no worker process on this machine")
    proc, err = figures._SPARE.pop()
    out, _ = proc.communicate(timeout=120)  # closes its stdin, as this process's end would
    err.close()
    assert proc.returncode == 0 and out.strip().endswith(b"{}")
