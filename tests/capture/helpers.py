"""Shared settings and checks of the capture tests."""

from __future__ import annotations

import numpy as np

from difflattice.capture import protocol as P
from difflattice.capture.emulator import EmulatorHandle, RigModel
from difflattice.capture.files import COLUMNS, Capture

PISTON = {"kind": "piston", "diameter_m": 0.0384, "sensitivity_uV": 50_000.0}
FAST_RIG = {
    "heartbeat_s": 0.1,
    "point_s": 0.002,
    "home_s": 0.02,
    "baud": 0,
    "temperature_c": 21.0,
    "drift_c_per_h": 0.0,
    "wobble_c": 0.0,
}
TIMEOUT_S = 0.6
"""Host link-down silence in tests (heartbeats every 0.1 s); other host timeouts scale from it."""
META = {"temperature_c": 21.0, "range_m": 1.0, "transducer_id": "T-38", "operator": "pytest"}


def assert_exact(capture: Capture, handle: EmulatorHandle) -> None:
    """Every point present exactly once, complete, with the values the emulated rig measures."""
    meta = capture.metadata
    n = meta["n_points"]
    assert capture.complete and not capture.missing
    np.testing.assert_array_equal(capture.seq, np.arange(n))
    if capture.kind == "lobe":
        cmd: P.Lobe | P.Wave = P.Lobe(
            meta["scan_id"], 0, n, meta["start_mdeg"], meta["step_mdeg"], meta["n_avg"], meta["cycles"], meta["freq_hz"]
        )
    else:
        cmd = P.Wave(
            meta["scan_id"],
            0,
            n,
            meta["x0_um"],
            meta["dx_um"],
            meta["z_um"],
            meta["n_avg"],
            meta["cycles"],
            meta["freq_hz"],
        )
    model = RigModel(handle.config)
    temperature = handle.config.rig.temperature_c
    expected = [model.measure(cmd, seq, temperature) for seq in range(n)]
    for column in COLUMNS[capture.kind][:-1]:
        np.testing.assert_array_equal(capture.columns[column], [getattr(m, column) for m in expected], err_msg=column)
