"""Shared test configuration: float64 available, strict rank promotion, a non-interactive backend;
each test module's compiled programs released after it."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
# The fit's disk cache of whole programs (`fit.program_cache`) is off for the suite: in-process CLI
# tests turn JAX's cache on, and a program traced under a test's monkeypatch would be stored under
# the key a user's fit computes. tests/fit/test_programs_cache.py tests it in directories of its own.
os.environ["DIFFLATTICE_PROGRAM_CACHE"] = "0"

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# strict rank promotion: an implicit broadcast between arrays of different rank (e.g. a (ny,)
# profile against an (nx, ny) field) is an error in the tests, so the library states its broadcasts
jax.config.update("jax_numpy_rank_promotion", "raise")


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's caches of compiled programs after each test module. Every XLA CPU executable
    maps its code into the process, and one pytest process that kept the whole suite's programs
    ran into the kernel's limit on memory maps (vm.max_map_count = 65530; measured 65233 maps
    and 6.4 GB resident before XLA failed to compile the next program and the process died)."""
    yield
    jax.clear_caches()
