"""The two-device sharding harness: a scene run on one device and split over two host devices
must give the same numbers. The host device count has to be set before JAX starts, so each case
runs its scene script in a subprocess; the script defines ``cases()`` yielding
``(one_device_result, two_device_result)`` pairs (`solver.loop.Result`), and the comparison below is
the only one (probes, peak map, phasors, final field, to 1e-12 of the probes' scale in float64)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

_PRELUDE = """
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
assert len(jax.devices()) == 2, jax.devices()
"""

_CHECK = """
n_cases = 0
for a, b in cases():
    assert len(b.final.pressure.sharding.device_set) == 2, b.final.pressure.sharding
    scale = float(jnp.abs(a.probes).max())
    assert scale > 1e-4, scale
    for u, v in ((a.probes, b.probes), (a.p_max, b.p_max), (a.phasors, b.phasors), (a.final.pressure, b.final.pressure)):
        err = float(jnp.abs(u - v).max())
        assert err <= 1e-12 * scale, err
    n_cases += 1
assert n_cases > 0
print("OK", n_cases)
"""


def assert_two_devices_match(scene_script: str, *, timeout_s: float = 600) -> None:
    """Run `scene_script` (defines ``cases()``) on two forced host devices and check each pair."""
    code = _PRELUDE + textwrap.dedent(scene_script) + _CHECK
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(Path(__file__).parent), env.get("PYTHONPATH")]))
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout_s)
    assert r.returncode == 0 and "OK" in r.stdout, r.stderr[-3000:]
