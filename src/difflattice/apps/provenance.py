"""Provenance of a program's result: package versions, the git commit, the machine and device,
and SHA-256 hashes of the config and data files (for `apps.fitting` and `apps.fitting_housed`)."""

from __future__ import annotations

import hashlib
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def provenance(config_path: Path | None, data_paths: list[Path] | tuple[Path, ...]) -> dict:
    """Package versions, git commit, machine, device and SHA-256 of the config and data files."""
    import equinox
    import jax
    import optimistix

    from .. import __version__

    try:
        commit = (
            subprocess.run(
                ["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5, cwd=Path(__file__).parent
            ).stdout.strip()
            or None
        )
    except (OSError, subprocess.SubprocessError):
        commit = None
    return {
        "difflattice": __version__,
        "versions": {
            "python": sys.version.split()[0],
            "jax": jax.__version__,
            "equinox": equinox.__version__,
            "optimistix": optimistix.__version__,
            "numpy": np.__version__,
        },
        "git_commit": commit,
        "machine": platform.machine(),
        "device": str(jax.devices()[0]),
        "config_sha256": _sha256(config_path) if config_path else None,
        "data_sha256": {str(p): _sha256(p) for p in data_paths},
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
