"""Fixtures for the capture tests: fast emulated rigs on real pseudo-terminals."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from difflattice.capture.emulator import EmulatorHandle, start_emulator

from .helpers import FAST_RIG, PISTON


@pytest.fixture
def start_rig(tmp_path: Path) -> Iterator[Callable[..., EmulatorHandle]]:
    """Start emulators (own processes) with fast timing; all are stopped after the test."""
    handles: list[EmulatorHandle] = []

    def start(**kw: Any) -> EmulatorHandle:
        kw.setdefault("transducer", PISTON)
        kw["rig"] = {**FAST_RIG, **kw.get("rig", {})}
        handle = start_emulator(link_path=tmp_path / f"rig{len(handles)}", **kw)
        handles.append(handle)
        return handle

    yield start
    for handle in handles:
        handle.stop()
