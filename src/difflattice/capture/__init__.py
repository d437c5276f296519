"""Capture of microphone measurements from the rig over serial (protocol v1), without JAX.

Modules: :mod:`.protocol` (framing, CRC, messages), :mod:`.host` (:class:`RigHost`,
:func:`capture_lobe`, :func:`capture_wave`), :mod:`.files` (capture files, :func:`load_capture`),
:mod:`.emulator` (the rig emulator, :func:`start_emulator`), :mod:`.groundtruth` (transducers the
emulator measures), :mod:`.cli` (``difflattice capture`` and ``difflattice rig``). See
``docs/capture.md``. Importing this package imports only :mod:`.errors`; the rest loads on use.
"""

from __future__ import annotations

import importlib
from typing import Any

from .errors import (
    CaptureError,
    CaptureFileError,
    PortBusy,
    PortNotFound,
    ProtocolVersionError,
    RigError,
    RigTimeout,
)

_LAZY = {
    "capture_lobe": "host",
    "capture_wave": "host",
    "RigHost": "host",
    "load_capture": "files",
    "Capture": "files",
    "start_emulator": "emulator",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'difflattice.capture' has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)


__all__ = [
    "CaptureError",
    "CaptureFileError",
    "PortBusy",
    "PortNotFound",
    "ProtocolVersionError",
    "RigError",
    "RigTimeout",
    *_LAZY,
]
