"""The command line's habits (issue 32): --version, -q/-v on every job, exit codes in every help,
--out checked before any work (an existing file refused with code 2, a non-empty directory
refused unless --overwrite clears it), Ctrl-C ending with one line and code 130, and a public
top level whose names mean one thing whatever was imported first."""

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import difflattice.cli as cli
from difflattice.cli import EXIT_CODES, INCOMPLETE, build_parser, main

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}


def test_version(capsys):
    from difflattice import __version__

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"difflattice {__version__}"


def test_every_job_has_quiet_verbose_and_the_exit_codes_in_its_help():
    leaves = list(cli._leaf_parsers(build_parser()))
    names = {leaf.prog for leaf in leaves}
    assert {"difflattice simulate", "difflattice fit", "difflattice demo", "difflattice capture lobe"} <= names
    for leaf in leaves:
        opts = leaf._option_string_actions
        assert {"-q", "--quiet", "-v", "--verbose"} <= set(opts), leaf.prog
        text = leaf.format_help()
        assert "exit codes:" in text and "130" in text, leaf.prog
        if "--out" in opts and leaf.prog.split()[-1] in cli._OUT_DIR_JOBS:
            assert "--overwrite" in opts, leaf.prog
    assert EXIT_CODES in build_parser().format_help()


def _never(*_a, **_k):
    raise AssertionError("the job started although --out was unusable")


def test_out_naming_an_existing_file_exits_2_before_any_work(tmp_path, capsys, monkeypatch):
    import difflattice.apps.scene_run as scene_run

    monkeypatch.setattr(scene_run, "run_scene", _never)
    target = tmp_path / "taken.txt"
    target.write_text("keep me\n")
    code = main(["simulate", str(ROOT / "data/scenes/fig02_polaroid.toml"), "--out", str(target)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "is an existing file" in err and str(target) in err, err
    assert target.read_text() == "keep me\n"


def test_a_non_empty_out_directory_is_refused_or_cleared_with_overwrite(tmp_path, capsys, monkeypatch):
    import difflattice.apps.scene_run as scene_run

    out = tmp_path / "out"
    (out / "frames").mkdir(parents=True)
    (out / "frames" / "frame_0000.png").write_bytes(b"old")
    (out / "old_field.png").write_bytes(b"old")
    monkeypatch.setattr(scene_run, "run_scene", _never)
    scene = str(ROOT / "data/scenes/fig02_polaroid.toml")
    assert main(["simulate", scene, "--out", str(out)]) == 2
    assert "not empty" in capsys.readouterr().err and (out / "old_field.png").exists()
    # --overwrite clears it, then the job runs (here it stops at once: the run is replaced)
    monkeypatch.setattr(scene_run, "run_scene", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))
    assert main(["simulate", scene, "--out", str(out), "--overwrite"]) == 130
    assert out.is_dir() and not any(out.iterdir())  # cleared; nothing written, so nothing to mark
    assert "interrupted (Ctrl-C): no output was written" in capsys.readouterr().err
    # an empty or new directory needs no flag
    assert cli._check_out(build_parser().parse_args(["simulate", scene, "--out", str(out)])) is None


def test_overwrite_never_clears_a_checkout_or_the_current_directory(tmp_path, monkeypatch):
    (tmp_path / "pyproject.toml").write_text("")
    monkeypatch.chdir(tmp_path)
    args = build_parser().parse_args(["gallery", "--out", ".", "--overwrite"])
    assert "source checkout" in cli._check_out(args)
    assert (tmp_path / "pyproject.toml").exists()


def test_an_interrupt_marks_partial_outputs(tmp_path, monkeypatch):
    out = tmp_path / "o"
    out.mkdir()
    (out / "field.png").write_bytes(b"half")
    monkeypatch.setitem(cli._SESSION, "out", out)
    monkeypatch.setitem(cli._SESSION, "command", "simulate")
    monkeypatch.setitem(cli._SESSION, "complete", False)
    line = cli._interrupted_line()
    assert line.startswith("interrupted (Ctrl-C)") and "partial" in line and INCOMPLETE in line
    assert "interrupted (Ctrl-C)" in (out / INCOMPLETE).read_text()


def test_quiet_prints_nothing_on_stdout(tmp_path, capsys):
    code = main(["simulate", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "o"), "-q"])
    cap = capsys.readouterr()
    assert code == 2 and cap.out == "" and "missing.toml" in cap.err


def _reader(stream, sink: list):
    while True:
        ch = stream.read(1)
        if not ch:
            return
        sink.append(ch)


def test_ctrl_c_during_simulate_exits_130_with_one_line(tmp_path):
    """SIGINT while `simulate` works (the progress line is up: compiling or stepping): one line on
    stderr, code 130, no traceback; what was written is marked partial."""
    out = tmp_path / "fig2"
    proc = subprocess.Popen(
        [sys.executable, "-m", "difflattice.cli", "simulate", str(ROOT / "data/scenes/fig02_polaroid.toml")]
        + ["--out", str(out), "--no-animation"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    err: list[str] = []
    t = threading.Thread(target=_reader, args=(proc.stderr, err), daemon=True)
    t.start()
    deadline = time.monotonic() + 120
    while "simulate" not in "".join(err) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, "".join(err)[-2000:]
    time.sleep(0.5)
    t_int = time.monotonic()
    proc.send_signal(signal.SIGINT)
    code = proc.wait(timeout=60)
    waited = time.monotonic() - t_int
    t.join(timeout=5)
    text = "".join(err)
    assert code == 130, text[-2000:]
    assert "Traceback" not in text, text[-3000:]
    lines = [ln for ln in text.replace("\r", "\n").splitlines() if "interrupted" in ln]
    assert len(lines) == 1 and lines[0].startswith("interrupted (Ctrl-C)"), text[-2000:]
    assert waited < 10, waited  # at once, not after the compiled piece returns
    if out.is_dir() and any(p.name != INCOMPLETE for p in out.iterdir()):
        # partial outputs are marked; a run that had finished before the interrupt took effect
        # (e.g. a warm cache: fig02 runs in well under a second) says its outputs are complete
        assert (out / INCOMPLETE).exists() or lines[0].endswith("are complete"), lines


def test_an_interrupt_turned_into_another_error_still_ends_with_one_line(tmp_path, monkeypatch, capsys):
    """Ctrl-C that lands inside an extension module's import comes out as `ImportError:
    initialization failed` (CI, matplotlib's ft2font), not as KeyboardInterrupt: still code 130
    and the one line; the same error without a Ctrl-C is a bug and is raised."""

    def interrupted_import(args, **kw):
        cli._SESSION["interrupted"] = True  # what the SIGINT handler records before raising
        raise ImportError("initialization failed")

    monkeypatch.setattr(cli, "_INTERRUPT_LOCK", threading.Lock())
    monkeypatch.setitem(cli._SESSION, "interrupted", False)
    monkeypatch.setattr(cli, "_run", interrupted_import)
    argv = ["simulate", str(ROOT / "data/scenes/fig02_polaroid.toml"), "--out", str(tmp_path / "o")]
    assert main(argv) == 130
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("interrupted (Ctrl-C)"), err

    def plain_bug(args, **kw):
        raise ImportError("initialization failed")

    monkeypatch.setattr(cli, "_INTERRUPT_LOCK", threading.Lock())
    monkeypatch.setitem(cli._SESSION, "interrupted", False)
    monkeypatch.setattr(cli, "_run", plain_bug)
    with pytest.raises(ImportError, match="initialization failed"):
        main(argv)


def test_the_top_level_names_do_not_change_with_import_order():
    code = (
        "import types, difflattice as dl\n"
        "assert isinstance(dl.air, types.ModuleType), dl.air\n"
        "g = dl.make_grid(frequency_hz=5e4, cells_per_wavelength=10, c_max_m_s=343.0, shape=(8, 8))\n"
        "assert isinstance(dl.air, types.ModuleType) and dl.air.speed_of_sound_m_s(20.0) > 340\n"
        "assert dl.air_material(20.0).name == 'air'\n"
        "for n in ('disc_transducer', 'far_field', 'far_field_rz', 'far_field_3d', 'load_scene', 'run_scene',\n"
        "          'run_scene3d', 'load_fit_config', 'run_fit', 'design_horn', 'lobe_metrics', 'level_db'):\n"
        "    assert callable(getattr(dl, n)), n\n"
        "import difflattice.lattice.medium\n"
        "assert isinstance(dl.air, types.ModuleType)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=ENV)
    assert r.returncode == 0, r.stderr[-2000:]


@pytest.mark.parametrize(
    "patch, key",
    [
        (("size_m = [0.03, 0.04]", "size_m = [-0.03, 0.04]"), "grid.size_m"),
        (("size_m = [0.03, 0.04]", "size_m = [0.0001, 0.04]"), "grid.size_m"),
        (("n_steps = 50", "n_steps = -5"), "run.n_steps"),
    ],
)
def test_scene_keys_out_of_range_are_refused_naming_the_key(tmp_path, capsys, patch, key):
    scene = tmp_path / "s.toml"
    scene.write_text(RZ_SCENE.replace(*patch))
    code = main(["simulate", str(scene), "--out", str(tmp_path / "o"), "-q"])
    err = capsys.readouterr().err
    assert code == 2 and f"[{key}]" in err and err.count("\n") == 1, err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


RZ_SCENE = """
[grid]
kind = "rz"
frequency_hz = 50000.0
cells_per_wavelength = 8.0
size_m = [0.03, 0.04]
[edges]
z_lo = "rigid"
thickness_cells = 6
[[transducers]]
type = "disc"
centre_m = [0.0, 0.0]
diameter_m = 0.0384
[farfield]
range_m = 1.0
angles_deg = [0.0, 90.0, 1.0]
[run]
n_steps = 50
"""


def test_the_small_rz_scene_runs(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text(RZ_SCENE)
    assert main(["simulate", str(scene), "--out", str(tmp_path / "o"), "-q", "--no-animation", "--no-frames"]) == 0


def test_the_watcher_ends_a_main_thread_that_does_not_stop(tmp_path):
    """A main thread that never stops by itself (here it swallows KeyboardInterrupt, as code
    waiting in XLA would not see it): the watcher ends the process INTERRUPT_GRACE_S after
    Ctrl-C, with one line and code 130, and marks the files written so far."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "half.png").write_bytes(b"x")
    code = (
        "import time, difflattice.cli as cli\n"
        "cli._install_interrupt_handler()\n"
        f"cli._SESSION.update(out={str(out)!r}, command='simulate', complete=False)\n"
        "end = time.time() + 60\n"
        "ready = False\n"
        "while time.time() < end:\n"
        "    try:\n"
        "        if not ready:  # inside the try: a Ctrl-C right after 'ready' is swallowed too\n"
        "            ready = True\n"
        "            print('ready', flush=True)\n"
        "        time.sleep(0.05)\n"
        "    except KeyboardInterrupt:\n"
        "        pass\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV
    )
    assert proc.stdout.readline().strip() == "ready"
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    rc = proc.wait(timeout=30)
    waited = time.monotonic() - t0
    err = proc.stderr.read()
    assert rc == 130, err
    assert cli.INTERRUPT_GRACE_S - 0.1 <= waited < cli.INTERRUPT_GRACE_S + 5, waited
    assert [ln for ln in err.splitlines() if ln.strip()] == [
        f"interrupted (Ctrl-C): the outputs in {out} are partial (marked by {out / INCOMPLETE})"
    ], err
    assert (out / INCOMPLETE).exists()


def test_a_misspelt_isolate_surface_is_refused_before_the_run(tmp_path, capsys):
    """`simulate --isolate NAME` with a name the scene has no surface of: code 2 and one line that
    names the scene's surfaces, before the (here 16-minute) run, nothing written."""
    out = tmp_path / "o"
    code = main(["simulate", str(ROOT / "data/scenes/corridor3d.toml"), "--out", str(out), "--isolate", "postt"])
    err = capsys.readouterr().err
    assert code == 2 and "postt" in err and "'post'" in err and "'wall x_hi'" in err, err
    assert not out.exists() or not any(out.iterdir())  # no run: nothing written
