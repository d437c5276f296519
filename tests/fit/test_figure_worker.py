"""The report's figure worker started ahead (`figures.prestart_worker`, issue 30: its matplotlib
import runs beside the fit): the next writer takes that process and draws with it; a spare that
died is not taken; one never taken exits when its input ends; a deferred figure goes to it when computed."""

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


def test_a_deferred_figure_goes_to_the_worker_when_computed(tmp_path):
    """With a worker process the deferred job is sent as soon as its arguments are computed (it is
    drawn beside the rest of the fit, not after it); its computation's error still reaches
    `results`."""
    import threading

    w = figures.FigureWriter(background=True)
    if w._proc is None:
        pytest.skip("no worker process on this machine")
    a = np.arange(-90, 91, 10.0)
    done = threading.Event()

    def compute():
        done.set()
        return (a, {"measured": (-np.abs(a) / 3, "o")}), {}

    w.defer("lobe", "lobe_plots", tmp_path / "lobe.png", compute)
    assert done.wait(60)
    name, _, _, t, box = w._deferred[0]
    t.join(60)
    assert name == "lobe" and "value" not in box and "error" not in box  # sent by its thread
    assert w.results()["lobe"].stat().st_size > 1000

    w2 = figures.FigureWriter(background=True)
    w2.defer("field", "field_image", tmp_path / "field.png", lambda: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        w2.results()
