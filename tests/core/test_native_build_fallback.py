"""The native build's fallbacks say what they did: a compiler that rejects -march=native gets a
generic build that is recorded (and reported by every later process); a timeout is retried by the
next process instead of leaving a slow or failed build cached."""

import subprocess
from pathlib import Path

import pytest

from difflattice.solver.native import build


class _Result:
    def __init__(self, returncode: int, stderr: str = ""):
        self.returncode, self.stderr, self.stdout = returncode, stderr, ""


def test_generic_build_is_recorded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    def fake_run(cmd, **kw):
        if "-march=native" in cmd:
            return _Result(1, "c++: error: unrecognized command-line option '-march=native'")
        Path(cmd[cmd.index("-o") + 1]).write_bytes(b"lib")
        return _Result(0)

    monkeypatch.setattr(build.subprocess, "run", fake_run)
    out = tmp_path / "k" / "liblattice.so"
    assert build._compile("c++", out, "/inc") is None
    assert out.read_bytes() == b"lib"
    note = (out.parent / build.GENERIC_NOTE).read_text()
    assert "without -march=native" in note and "unrecognized command-line option" in note
    assert "without -march=native" in capsys.readouterr().err


def test_timeout_is_transient_and_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []

    def fake_run(cmd, **kw):
        calls.append(cmd)
        raise subprocess.TimeoutExpired(cmd, kw.get("timeout", 0))

    monkeypatch.setattr(build.subprocess, "run", fake_run)
    out = tmp_path / "k" / "liblattice.so"
    err = build._compile("c++", out, "/inc")
    assert isinstance(err, build._Transient) and "tries again" in err
    assert len(calls) == 1  # no generic build after a timeout
    assert not out.exists() and not (out.parent / build.GENERIC_NOTE).exists()
    assert list(out.parent.iterdir()) == []  # the temporary file is gone
