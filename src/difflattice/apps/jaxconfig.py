"""Process-wide JAX settings for the command line and scripts (not applied on import of the
library): float64 available, and a persistent compilation cache so that a re-run of a fit or a
scene in a new process does not compile again.

The cache lives in ``$DIFFLATTICE_CACHE_DIR`` (default ``~/.cache/difflattice/xla``); set it to
``0`` to disable. ``$DIFFLATTICE_CACHE_MIN_COMPILE_S`` (default 0: cache every program) is the
compile time below which a program is not cached. With it on, the fit's small programs and the
lattice runs on the native kernels are also kept whole (traced, lowered and compiled) in its
``programs/`` folder (`solver.program_cache`: a warm fit neither traces nor lowers them, and loads
them in a thread as the last run used them); ``DIFFLATTICE_PROGRAM_CACHE=0`` keeps only JAX's cache.
"""

from __future__ import annotations

import os
from pathlib import Path


def configure(*, x64: bool = True) -> None:
    import jax

    if x64:
        jax.config.update("jax_enable_x64", True)
    where = os.environ.get("DIFFLATTICE_CACHE_DIR", str(Path.home() / ".cache" / "difflattice" / "xla"))
    if where != "0":
        try:
            Path(where).mkdir(parents=True, exist_ok=True)
            jax.config.update("jax_compilation_cache_dir", where)
            # every program, however small: a fit compiled ~150 small ones (eager jnp ops,
            # 20-60 ms each, 4.5 s in all), which a 0.2 s threshold never cached (issue 15;
            # since session 8 the fit's set-up avoids most of them: 81 programs per fit)
            min_s = float(os.environ.get("DIFFLATTICE_CACHE_MIN_COMPILE_S", "0"))
            jax.config.update("jax_persistent_cache_min_compile_time_secs", min_s)
        except OSError:  # read-only home: run without the cache
            pass
