"""The disk cache of compiled programs, where the fit's small programs (`programs.small_jit`) are
kept whole across processes: it lives in `difflattice.solver.program_cache` (the lattice runs'
programs use it too); this module is its earlier name."""

from __future__ import annotations

from ..solver.program_cache import CachedProgram, cache_dir, package_fingerprint

__all__ = ["CachedProgram", "cache_dir", "package_fingerprint"]
