"""The disk cache of compiled programs (`solver.program_cache`, issue 30): for the fit's small
programs, a hit gives the same bits as tracing afresh, in this process and in a new one; a
changed shape, static value, package source or package version misses; a corrupt file is ignored
without an error; a value the key cannot describe falls back to the ordinary path. For a lattice
run on the native kernels (`simulate`, eagerly), the stored program gives the same bits in a new
process and a program whose kernels are not registered is neither loaded nor stored."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from difflattice.fit.programs import SMALL_PROGRAM_OPTIONS, small_jit
from difflattice.solver import program_cache as pc

jax.config.update("jax_enable_x64", True)


class Settings(eqx.Module):
    """A model-like argument: arrays (program inputs) beside static fields (part of the key)."""

    weights: jax.Array
    label: str = eqx.field(static=True)
    power: int = eqx.field(static=True)


def program(s: Settings, params: dict, scale: float):
    """Uses LAPACK (a solve) and returns a non-array output beside the arrays."""
    a = jnp.eye(s.weights.shape[0]) * 2.0 + jnp.outer(s.weights, s.weights) * 0.1
    x = jnp.linalg.solve(a, s.weights * params["gain"])
    return {"x": x**s.power * scale, "norm": jnp.sum(x * x), "label": s.label + "!"}


def _args(n: int = 5, power: int = 2, scale: float = 1.5):
    s = Settings(jnp.linspace(0.1, 1.0, n), "line", power)
    return (s, {"gain": jnp.asarray(3.0)}, scale)


def _same(a, b) -> bool:
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    return ta == tb and all(
        (np.asarray(x).dtype == np.asarray(y).dtype and np.array_equal(np.asarray(x), np.asarray(y)))
        if eqx.is_array(x)
        else x == y
        for x, y in zip(la, lb, strict=True)
    )


@pytest.fixture
def cache(tmp_path, monkeypatch):
    where = tmp_path / "programs"
    monkeypatch.setattr(pc, "cache_dir", lambda: where)
    return where


def _fresh() -> pc.CachedProgram:
    """A program with an empty memory: what a new process sees (the disk only)."""
    return pc.CachedProgram(program, SMALL_PROGRAM_OPTIONS)


def _reference(*args):
    return eqx.filter_jit(program, compiler_options=dict(SMALL_PROGRAM_OPTIONS))(*args)


def test_hit_gives_the_same_bits_as_tracing_afresh(cache):
    args = _args()
    first = _fresh()(args, {})
    files = sorted(cache.glob("*.prog"))
    assert len(files) == 1
    loads = []
    real_load = pc._load
    second = _fresh()
    pc_load = lambda path, n: loads.append((path, real_load(path, n))) or loads[-1][1]  # noqa: E731
    with pytest.MonkeyPatch.context() as m:
        m.setattr(pc, "_load", pc_load)
        got = second(args, {})
    assert loads and loads[0][0] == files[0] and loads[0][1] is not None  # read from disk
    assert _same(got, first) and _same(got, _reference(*args))
    assert got["label"] == "line!"


def test_small_jit_uses_the_cache_and_agrees_with_filter_jit(cache):
    f = small_jit(program)
    args = _args(n=4)
    assert _same(f(*args), _reference(*args))
    assert len(list(cache.glob("*.prog"))) == 1


@pytest.mark.parametrize(
    "other",
    [
        pytest.param(lambda: _args(n=6), id="shape"),
        pytest.param(lambda: _args(power=3), id="static field"),
        pytest.param(lambda: _args(scale=2.5), id="static scalar"),
    ],
)
def test_changed_arguments_miss(cache, other):
    _fresh()(_args(), {})
    args = other()
    got = _fresh()(args, {})
    assert len(list(cache.glob("*.prog"))) == 2
    assert _same(got, _reference(*args))


def test_changed_source_or_version_misses(cache, monkeypatch):
    args = _args()
    _fresh()(args, {})
    real = pc.package_fingerprint()
    monkeypatch.setattr(pc, "package_fingerprint", lambda: real + "edited")
    _fresh()(args, {})
    assert len(list(cache.glob("*.prog"))) == 2
    monkeypatch.undo()
    monkeypatch.setattr(pc, "cache_dir", lambda: cache)
    version = pc.importlib.metadata.version
    monkeypatch.setattr(pc.importlib.metadata, "version", lambda n: "99.0" if n == "jax" else version(n))
    pc.package_fingerprint.cache_clear()
    try:
        assert pc.package_fingerprint() != real
        _fresh()(args, {})
    finally:
        monkeypatch.undo()
        pc.package_fingerprint.cache_clear()
    assert len(list(cache.glob("*.prog"))) == 3


@pytest.mark.parametrize("garbage", [b"", b"not a pickle", b"\x80\x04K\x01."], ids=["empty", "text", "an int"])
def test_corrupt_file_is_ignored_and_replaced(cache, garbage):
    args = _args()
    _fresh()(args, {})
    (path,) = cache.glob("*.prog")
    path.write_bytes(garbage)
    got = _fresh()(args, {})  # no error: recompiled
    assert _same(got, _reference(*args))
    assert pc._load(path, 2) is not None  # rewritten whole


def test_a_loaded_program_that_cannot_run_is_dropped(cache, monkeypatch):
    """A stored executable that loads but fails at its first run (as one JAX had read from its own
    cache did: "Function ... not found") costs its file, not the fit: the ordinary path answers."""
    args = _args()
    _fresh()(args, {})
    (path,) = cache.glob("*.prog")

    def broken(*_):
        raise jax.errors.JaxRuntimeError("NOT_FOUND: Function fusion not found")

    real = pc._from_bytes
    monkeypatch.setattr(pc, "_from_bytes", lambda *a: dataclasses.replace(real(*a), compiled=broken))
    p = _fresh()
    assert p(args, {}) is NotImplemented and not path.exists()
    assert _same(small_jit(program)(*args), _reference(*args))


def test_a_value_without_a_stable_description_falls_back(cache):
    lock = threading.Lock()  # hashable, but no fields, state or name to key it on
    with pytest.raises(pc.Unkeyable):
        pc._encode_static(lock)
    f = small_jit(lambda x, token: x * 2.0)
    assert np.array_equal(np.asarray(f(jnp.arange(3.0), lock)), [0.0, 2.0, 4.0])
    assert not list(cache.glob("*.prog"))


def test_a_changed_jax_setting_is_another_program(cache):
    """In memory as on disk: a setting that changes tracing (here the matmul precision) is part of
    the key, as it is of `jit`'s."""
    p, args = _fresh(), _args()
    p(args, {})
    with jax.default_matmul_precision("highest"):
        p(args, {})
    assert len(p.memory) == 2 and len(list(cache.glob("*.prog"))) == 2


def test_a_source_written_during_the_process_turns_the_disk_cache_off(cache, monkeypatch):
    """The running code may then differ from the sources the fingerprint hashes: nothing is read
    or stored (the result is still right)."""
    monkeypatch.setattr(pc, "_IMPORTED_NS", 0)  # every source file is newer than this process
    args = _args()
    assert _same(_fresh()(args, {}), _reference(*args))
    assert not list(cache.glob("*.prog"))


def test_stale_generations_are_removed(cache, monkeypatch):
    """Files of another fingerprint unused for STALE_DAYS and day-old temporary files go when a
    process first stores; recent files of another fingerprint (another checkout) stay."""
    cache.mkdir(parents=True)
    month_ago = time.time() - 30 * 86400
    old, recent, tmp = (cache / "0000000000000000-a.prog", cache / "1111111111111111-b.prog", cache / "x.1.2.tmp")
    for p in (old, recent, tmp):
        p.write_bytes(b"x")
    for p in (old, tmp):
        os.utime(p, (month_ago, month_ago))
    pc._evict_stale.cache_clear()
    _fresh()(_args(), {})
    names = {p.name for p in cache.iterdir()}
    assert recent.name in names and old.name not in names and tmp.name not in names
    assert sum(n.startswith(pc.package_fingerprint()[:16]) for n in names) == 1


def test_off_without_a_cache_dir(monkeypatch):
    monkeypatch.setattr(pc, "cache_dir", lambda: None)
    assert _fresh()(_args(), {}) is NotImplemented


SCRIPT = textwrap.dedent(
    """
    import sys
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    from difflattice.solver import program_cache as pc
    from difflattice.fit.programs import small_jit

    where = pc.Path(sys.argv[1])
    pc.cache_dir = lambda: where
    loaded = []
    real = pc._load
    pc._load = lambda p, n: loaded.append(real(p, n)) or loaded[-1]

    @small_jit
    def fit_like(a, b):
        return jnp.linalg.solve(a, b), jnp.linalg.qr(a)[1]

    a = jnp.asarray(np.random.default_rng(0).normal(size=(6, 6)) + 6 * np.eye(6))
    x, r = fit_like(a, jnp.arange(6.0))
    print("hit" if loaded[0] is not None else "miss", np.asarray(x).tobytes().hex(), np.asarray(r).tobytes().hex())
    """
)


def test_a_new_process_loads_the_program_and_runs_it(tmp_path):
    """Loaded without tracing, a program must still find what lowering sets up (LAPACK's kernels:
    without it the first call crashed)."""
    env = dict(os.environ, PYTHONPATH=str(Path(pc.__file__).resolve().parents[2]), DIFFLATTICE_PROGRAM_CACHE="1")
    runs = [
        subprocess.run(
            [sys.executable, "-c", SCRIPT, str(tmp_path)], capture_output=True, text=True, env=env, timeout=300
        )
        for _ in range(2)
    ]
    for r in runs:
        assert r.returncode == 0, r.stderr[-2000:]
    first, second = (r.stdout.split() for r in runs)
    assert first[0] == "miss" and second[0] == "hit"
    assert first[1:] == second[1:]


def test_a_program_calling_an_unknown_kernel_is_not_stored():
    """A stored program may call LAPACK (set up before loading) but no other custom call: a kernel
    registered lazily (e.g. the native lattice's FFI targets) could be missing in the process that
    loads it, which would crash it rather than raise."""
    from difflattice.solver import program_cache as pc

    class Stub:
        def __init__(self, text):
            self.text = text
            self._executable = type("E", (), {"_unloaded_executable": None})()

        def as_text(self):
            return self.text

    with pytest.raises(ValueError, match="difflattice_leapfrog"):
        pc._serialise(Stub('x = f32[4] custom-call(y), custom_call_target="difflattice_leapfrog"'), None, 1)


def test_stored_output_structure_keeps_equinox_sentinels():
    """An output skeleton holding a PyTreeDef of an equinox module (as an optimiser state's
    linear operator does: its input structure) must come back equal: pickled by value, equinox's
    MISSING sentinel inside it came back as a new object, the structures compared unequal, and the
    next program traced on that output failed ("different pytree metadata") once some programs
    were loaded and others compiled."""
    import pickle

    import jax
    import jax.numpy as jnp

    from difflattice.fit.model import LineParams
    from difflattice.solver import program_cache as pc

    p = LineParams(**{f.name: jnp.zeros(()) for f in dataclasses.fields(LineParams)})
    tree = jax.tree_util.tree_structure(p)
    assert pickle.loads(pickle.dumps(tree)) != tree  # the defect this guards against
    assert pc._load_skeleton(pc._dump_skeleton({"in_structure": tree})) == {"in_structure": tree}


def _session_run(cache, monkeypatch, sizes) -> tuple[pc._Session, list]:
    """A new "process": a fresh session and fresh programs, called on arguments of these sizes."""
    session = pc._Session()
    monkeypatch.setattr(pc, "_SESSION", session)
    p = _fresh()
    return session, [p(_args(n=n), {}) for n in sizes]


def test_the_next_process_preloads_the_programs_of_the_last(cache, monkeypatch):
    """The programs a process used are listed under its first program's key; a process starting
    with the same program loads the others in a thread, and they give the same bits."""
    sizes = (3, 4, 5, 6)
    _, first = _session_run(cache, monkeypatch, sizes)
    (manifest,) = cache.glob("*.manifest")
    assert len(manifest.read_text().split()) == len(sizes)
    taken = []
    real = pc._Session.take
    monkeypatch.setattr(pc._Session, "take", lambda self, p: taken.append(real(self, p)) or taken[-1])
    written = manifest.stat().st_mtime_ns
    session = pc._Session()
    monkeypatch.setattr(pc, "_SESSION", session)
    p = _fresh()
    second = [p(_args(n=sizes[0]), {})]  # tells which manifest to read: the thread starts
    deadline = time.monotonic() + 120
    while not all(f.done() for f in session.pending.values()) and time.monotonic() < deadline:
        time.sleep(0.01)
    second += [p(_args(n=n), {}) for n in sizes[1:]]
    assert all(_same(a, b) for a, b in zip(first, second, strict=True))
    assert taken[0] is None  # the first program the caller loads itself
    assert len(taken) == len(sizes) and all(e is not None for e in taken[1:])  # the others preloaded
    assert not session.pending and manifest.stat().st_mtime_ns == written  # the same order: not rewritten


def test_a_manifest_naming_missing_or_corrupt_files_costs_nothing(cache, monkeypatch):
    sizes = (3, 4, 5)
    _, first = _session_run(cache, monkeypatch, sizes)
    progs = sorted(cache.glob("*.prog"), key=lambda p: p.stat().st_mtime_ns)
    progs[1].unlink()
    progs[2].write_bytes(b"garbage")
    _, second = _session_run(cache, monkeypatch, sizes)
    assert all(_same(a, b) for a, b in zip(first, second, strict=True))
    assert pc._load(progs[2], 2) is not None  # recompiled and stored whole


def test_another_order_rewrites_the_manifest(cache, monkeypatch):
    _session_run(cache, monkeypatch, (3, 4, 5))
    (manifest,) = cache.glob("*.manifest")
    before = manifest.read_text().split()
    _session_run(cache, monkeypatch, (3, 5, 4))
    after = manifest.read_text().split()
    assert sorted(before) == sorted(after) and before != after
