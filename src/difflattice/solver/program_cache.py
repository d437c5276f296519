"""A disk cache of compiled programs, so that a new process neither traces nor lowers them again
(issue 30: tracing and lowering ~40 programs was most of a warm fit's start-up). Used by the fit's
small programs (`fit.programs.small_jit`) and by the lattice runs on the native kernels
(`solver.loop.simulate`, called eagerly).

JAX's persistent compilation cache skips XLA's compilation only: its key is the lowered program,
so every process still traces the Python function and lowers it to StableHLO before it can ask.
Here a program is keyed on what determines it *before* tracing, and the compiled executable is
stored whole (`jax.experimental.serialize_executable`):

- the function's module and qualified name;
- the arguments' pytree structure (node types and their static data, e.g. an equinox module's
  static fields), the static leaves' values, and the shape, dtype and weak type of every array
  leaf (array leaves are the program's inputs, as in `equinox.filter_jit`);
- a hash of the package's sources, the versions of jax, jaxlib, equinox, optimistix,
  lineax and numpy, the JAX settings that change tracing (x64, matmul precision, promotion),
  `XLA_FLAGS`/`EQX_ON_ERROR`, the compiler options, the backend and the host CPU's features;
- for a program calling custom kernels (`Kernels`: the native lattice kernels' FFI targets), what
  else the trace reads (their settings) and the kernels' library.

Values the key cannot describe without a memory address (an object with neither dataclass
fields nor a stable repr), programs with host callbacks or effects, programs calling a custom
kernel not declared (`Kernels`) or not registered in this process, any error in reading, loading
or writing an entry, and a loaded program whose first run fails (its file is removed) fall back
silently to the ordinary path (`equinox.filter_jit` and JAX's own cache). The cache is used where
JAX's persistent cache is on (`apps.jaxconfig.configure` sets it for the command line): its files
live in ``<jax_compilation_cache_dir>/programs``. ``DIFFLATTICE_PROGRAM_CACHE=0`` turns it off.

A process lists the programs it used, in order, under its first program's key (a manifest); the
next process whose first program has that key loads the rest in a thread meanwhile (`_Session`;
``DIFFLATTICE_PROGRAM_PRELOAD=0`` turns that off).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
import importlib.metadata
import io
import os
import pickle
import platform
import re
import sys
import threading
import time
import types
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import numpy as np
from jax._src import config as jax_config

__all__ = ["CachedProgram", "Kernels", "cache_dir", "package_fingerprint"]

FORMAT = 4
"""The layout of a cache file; a file of another layout is a miss."""

_JAX_SETTINGS = (
    "jax_enable_x64",
    "jax_default_matmul_precision",
    "jax_numpy_rank_promotion",
    "jax_numpy_dtype_promotion",
    "jax_default_prng_impl",
    "jax_enable_checks",
    "jax_debug_nans",
    "jax_debug_infs",
    "jax_disable_jit",
)
_ENV = ("XLA_FLAGS", "EQX_ON_ERROR", "EQX_ON_ERROR_BREAKPOINT_FRAMES", "JAX_PLATFORMS")
_PACKAGES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "numpy")
_MAX_DEPTH = 64
STALE_DAYS = 14.0
"""Files of other package sources or versions (another fingerprint) older than this are removed
when a process first stores a program (a source edit leaves a generation of ~3 MB behind)."""


class Unkeyable(Exception):
    """A value the disk key cannot describe stably across processes (falls back to tracing)."""


class _Slot:
    """Where an array output goes in a stored output skeleton."""

    __slots__ = ()

    def __reduce__(self):
        return (_Slot, ())


def _is_slot(x: Any) -> bool:
    return isinstance(x, _Slot)


def cache_dir() -> Path | None:
    """The program cache's directory, or None where it is off (no JAX persistent cache, or
    ``DIFFLATTICE_PROGRAM_CACHE=0``)."""
    if os.environ.get("DIFFLATTICE_PROGRAM_CACHE", "1") == "0":
        return None
    where = jax_config.compilation_cache_dir.value
    return None if not where else Path(where) / "programs"


_IMPORTED_NS = time.time_ns()


@functools.cache
def _sources() -> tuple[Path, ...]:
    root = Path(__file__).resolve().parents[1]  # Python and native sources alike (conservative)
    return tuple(sorted(p for p in root.rglob("*") if p.suffix in (".py", ".cc", ".h") and p.is_file()))


def _sources_unchanged() -> bool:
    """Whether no source file was written since this module was imported: where one was, the
    running code may not be what the fingerprint hashes, and the disk cache is not used."""
    try:
        return all(p.stat().st_mtime_ns < _IMPORTED_NS for p in _sources())
    except OSError:
        return False


@functools.cache
def package_fingerprint() -> str:
    """A hash of difflattice's sources (Python and native) and the versions of the packages that trace the
    programs: a change to either is a miss."""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parents[1]
    for p in _sources():
        h.update(str(p.relative_to(root)).encode())
        h.update(p.read_bytes())
    for name in _PACKAGES:
        try:
            h.update(f"{name}={importlib.metadata.version(name)};".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"{name}=?;".encode())
    h.update(f"python={sys.version_info[:3]};machine={platform.machine()};".encode())
    try:  # executables are compiled for this CPU's features
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            flags = next((line for line in f if line.startswith(("flags", "Features"))), "")
        h.update(flags.encode())
    except OSError:
        h.update(platform.processor().encode())
    return h.hexdigest()


def _environment() -> str:
    """What beyond the sources and arguments changes a traced or compiled program."""
    settings = ",".join(f"{k}={getattr(jax.config, k, None)!r}" for k in _JAX_SETTINGS)
    env = ",".join(f"{k}={os.environ.get(k)!r}" for k in _ENV)
    dev = jax.devices()[0]
    backend = f"{dev.platform}:{dev.client.platform_version}:{dev.device_kind}:{len(jax.devices())}"
    return f"{settings};{env};{backend}"


def _name(obj: Any) -> str:
    module, qual = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if not isinstance(module, str) or not isinstance(qual, str):
        raise Unkeyable(f"{type(obj).__name__} without a module and qualified name")
    return f"{module}.{qual}"


def _encode_static(obj: Any, depth: int = 0) -> str:
    """A text that determines `obj` as a constant of a traced program, the same in every process
    (no memory addresses): arrays by value, dataclasses (equinox modules) field by field,
    functions by name and closure."""
    if depth > _MAX_DEPTH:
        raise Unkeyable("nested too deep")
    d = depth + 1
    if obj is None or isinstance(obj, (bool, int, float, complex, str, bytes)):
        return f"{type(obj).__name__}:{obj!r}"
    if isinstance(obj, enum.Enum):
        return f"enum:{_name(type(obj))}.{obj.name}"
    if isinstance(obj, (np.ndarray, np.generic, jax.Array)):
        a = np.asarray(obj)
        return f"const:{a.dtype.str}{a.shape}:{hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()}"
    if isinstance(obj, np.dtype):
        return f"dtype:{obj.str}"
    if isinstance(obj, (tuple, list)):
        return f"{type(obj).__name__}[" + ",".join(_encode_static(x, d) for x in obj) + "]"
    if isinstance(obj, (set, frozenset)):
        return f"{type(obj).__name__}{{" + ",".join(sorted(_encode_static(x, d) for x in obj)) + "}"
    if isinstance(obj, Mapping):
        items = sorted((_encode_static(k, d), _encode_static(v, d)) for k, v in obj.items())
        return f"{_name(type(obj))}{{" + ",".join(f"{k}:{v}" for k, v in items) + "}"
    if isinstance(obj, type):
        return f"type:{_name(obj)}"
    if isinstance(obj, jax.tree_util.PyTreeDef):
        return f"treedef:{_encode_tree(obj, d)}"
    if isinstance(obj, functools.partial):
        return f"partial({_encode_static(obj.func, d)},{_encode_static(obj.args, d)},{_encode_static(obj.keywords, d)})"
    if isinstance(obj, types.MethodType):
        return f"method({_encode_static(obj.__self__, d)},{_encode_static(obj.__func__, d)})"
    if isinstance(obj, types.FunctionType):
        cells = tuple(c.cell_contents for c in obj.__closure__ or ())
        return f"fn:{_name(obj)}({_encode_static(cells, d)};{_encode_static(obj.__defaults__, d)})"
    if dataclasses.is_dataclass(obj):  # equinox modules too
        fields = ",".join(f"{f.name}={_encode_static(getattr(obj, f.name, None), d)}" for f in dataclasses.fields(obj))
        return f"dc:{_name(type(obj))}({fields})"
    if callable(obj) and isinstance(getattr(obj, "__qualname__", None), str):  # builtins, jnp functions
        return f"callable:{_name(obj)}"
    state = getattr(obj, "__dict__", None)
    slots = getattr(type(obj), "__slots__", ())
    if isinstance(state, dict) or slots:  # a plain object (a sentinel, a settings holder): by its state
        names = sorted(
            set(state or ()) | {n for n in ([slots] if isinstance(slots, str) else slots) if hasattr(obj, n)}
        )
        return f"obj:{_name(type(obj))}(" + ",".join(f"{n}={_encode_static(getattr(obj, n), d)}" for n in names) + ")"
    raise Unkeyable(f"a {type(obj).__name__} has no stable description")


def _encode_tree(treedef: Any, depth: int = 0) -> str:
    """The pytree structure: node types and their static data (not the leaves)."""
    if depth > _MAX_DEPTH:
        raise Unkeyable("nested too deep")
    if treedef.num_nodes == 1 and treedef.num_leaves == 1:
        return "*"
    data = treedef.node_data()
    if data is None:
        return "None" if treedef.num_leaves == 0 else "*"
    kind, aux = data
    children = ",".join(_encode_tree(c, depth + 1) for c in treedef.children())
    return f"{_name(kind)}<{_encode_static(aux)}>({children})"


def _aval(x: Any) -> tuple:
    """(shape, dtype, weak type) of an array argument, as `jit` sees it."""
    if isinstance(x, jax.Array):
        return (x.shape, x.dtype.str, bool(getattr(x, "weak_type", False)))
    a = np.asarray(x)
    return (a.shape, a.dtype.str, False)


@dataclasses.dataclass
class _Entry:
    """A loaded program: the executable and where its outputs go."""

    compiled: Any
    skeleton: Any
    path: Path | None  # loaded from here and not yet run (None: compiled here, or has run)
    n_in: int = -1  # array inputs (-1: not checked)

    def __post_init__(self):
        leaves, self.out_tree = jax.tree_util.tree_flatten(self.skeleton, is_leaf=_is_slot)
        self.out_leaves = list(leaves)
        self.slots = [i for i, x in enumerate(leaves) if _is_slot(x)]

    def outputs(self, arrays) -> Any:
        """The program's output pytree from its array outputs."""
        leaves = list(self.out_leaves)
        for i, a in zip(self.slots, arrays, strict=True):
            leaves[i] = a
        return jax.tree_util.tree_unflatten(self.out_tree, leaves)


_FALLBACK = object()


@dataclasses.dataclass(frozen=True)
class Kernels:
    """Custom kernels (XLA custom-call targets) a stored program may call beside LAPACK's: a
    kernel missing in the process that loads the program would crash that process, not raise,
    so a program is loaded (and stored) only after `ready()` has registered them.

    - `targets`: the custom-call target names;
    - `ready()`: registers them in this process; False where they are not available (then the
      program is neither loaded nor stored: the ordinary path runs);
    - `key()`: what else fixes the compiled program that the arguments do not show (settings
      the trace reads, e.g. thread counts; the kernels' library)."""

    targets: frozenset[str]
    ready: Callable[[], bool]
    key: Callable[[], str]


class CachedProgram:
    """`fn` as top-level programs compiled with `compiler_options`, kept in memory per argument
    signature and on disk across processes (see the module docstring). `__call__` returns
    `NotImplemented` where the caller should run its ordinary path instead. `kernels`: the
    custom kernels `fn` may call (`Kernels`); any other custom call is not stored."""

    def __init__(self, fn: Callable, compiler_options: Mapping[str, Any], *, kernels: Kernels | None = None):
        self.fn = fn
        self.options = dict(compiler_options)
        self.kernels = kernels
        self.memory: dict[Any, Any] = {}
        self.lock = threading.Lock()
        self._locks: dict[Any, threading.Lock] = {}

    def __call__(self, args: tuple, kwargs: dict) -> Any:
        where = cache_dir()
        if where is None:
            return NotImplemented
        leaves, treedef = jax.tree_util.tree_flatten((args, kwargs))
        is_dyn = tuple(eqx.is_array(x) for x in leaves)
        dyn = [x for x, d in zip(leaves, is_dyn, strict=True) if d]
        static = tuple(x for x, d in zip(leaves, is_dyn, strict=True) if not d)
        avals = tuple(_aval(x) for x in dyn)
        try:
            # JAX's settings as `jit` keys on them (x64, precision, ...: a process may change them)
            mkey = (treedef, is_dyn, static, avals, where, jax_config.trace_context())
            entry = self.memory.get(mkey)
        except TypeError:  # an unhashable static leaf: equinox refuses it with its own message
            return NotImplemented
        if entry is None:
            with self.lock:  # one resolution per signature; other signatures resolve meanwhile
                lock = self._locks.setdefault(mkey, threading.Lock())
            with lock:
                entry = self.memory.get(mkey)
                if entry is None:
                    entry = self._resolve(where, leaves, treedef, is_dyn, dyn, static, avals)
                    self.memory[mkey] = entry
        if entry is _FALLBACK:
            return NotImplemented
        if entry.path is None:
            return entry.outputs(entry.compiled(*dyn))
        try:  # the first run of a loaded program, waited for: one that cannot run is dropped
            outs = jax.block_until_ready(entry.compiled(*dyn))
        except jax.errors.JaxRuntimeError:
            self.memory[mkey] = _FALLBACK
            entry.path.unlink(missing_ok=True)
            return NotImplemented
        entry.path = None  # ran: from now on as a program compiled here
        return entry.outputs(outs)

    # -- resolution: disk or compile ------------------------------------------------------------

    def _key(self, treedef, static, avals) -> str:
        text = "|".join(
            (
                f"format={FORMAT}",
                _name(self.fn),
                _encode_tree(treedef),
                _encode_static(static),
                repr(avals),
                repr(sorted(self.options.items())),
                package_fingerprint(),
                _environment(),
                "" if self.kernels is None else f"kernels={sorted(self.kernels.targets)}:{self.kernels.key()}",
            )
        )
        return hashlib.sha256(text.encode()).hexdigest()

    def _resolve(self, where: Path, leaves, treedef, is_dyn, dyn, static, avals) -> Any:
        if self.kernels is not None and not self.kernels.ready():
            return _FALLBACK
        try:
            key = self._key(treedef, static, avals)
        except Unkeyable:
            return _FALLBACK
        path = where / f"{package_fingerprint()[:16]}-{key}.prog"
        usable = _sources_unchanged()
        entry = None
        if usable:
            _SESSION.begin(where, key)
            entry = _SESSION.take(path)
            if entry is None or entry.n_in != len(dyn):
                entry = _load(path, len(dyn))
        if entry is not None:
            if self.kernels is None:
                _SESSION.record(path)
            return entry
        compiled, skeleton, payload = self._compile(leaves, treedef, is_dyn, dyn)
        if payload is not None and usable and _sources_unchanged():
            _store(path, payload)
            if self.kernels is None:
                _SESSION.record(path)
        return _Entry(compiled, skeleton, None)

    def _compile(self, leaves, treedef, is_dyn, dyn):
        """Trace, lower and compile `fn` on its array leaves; the output skeleton comes from the
        trace. Returns (compiled, skeleton, bytes to store or None)."""
        template = list(leaves)
        index = [i for i, d in enumerate(is_dyn) if d]
        skeletons: list = []

        def flat(*arrays):
            full = list(template)
            for i, a in zip(index, arrays, strict=True):
                full[i] = a
            args, kwargs = jax.tree_util.tree_unflatten(treedef, full)
            out = self.fn(*args, **kwargs)
            out_leaves, out_tree = jax.tree_util.tree_flatten(out)
            arrays_out = [x for x in out_leaves if eqx.is_array(x)]
            skeletons.append(
                jax.tree_util.tree_unflatten(out_tree, [_Slot() if eqx.is_array(x) else x for x in out_leaves])
            )
            return arrays_out

        # A name of its own (a module JAX's cache holds for no other path) and no write to JAX's
        # cache: the executable must be compiled here, not read from JAX's cache, since one that
        # JAX loaded from its cache serialises without its code (it loads, then fails to run:
        # "Function ... not found").
        flat.__name__ = flat.__qualname__ = f"cached_{getattr(self.fn, '__name__', 'program')}"
        hits = _cache_hits()
        with jax_config.persistent_cache_min_compile_time_secs(float("inf")):
            compiled = jax.jit(flat, compiler_options=self.options).lower(*dyn).compile()
        skeleton = skeletons[-1]
        payload = None
        if _cache_hits() == hits:
            try:
                payload = _serialise(compiled, skeleton, len(dyn), self.kernels)
            except Exception:  # noqa: BLE001 - not storable (callbacks, effects, constants, pickling)
                payload = None
        return compiled, skeleton, payload


_LOCAL = threading.local()


def _count_hit(event: str, **_: Any) -> None:
    if event == "/jax/compilation_cache/cache_hits":
        _LOCAL.hits = getattr(_LOCAL, "hits", 0) + 1


jax.monitoring.register_event_listener(_count_hit)


def _cache_hits() -> int:
    """How many programs this thread has read from JAX's persistent cache."""
    return getattr(_LOCAL, "hits", 0)


_SAFE_CUSTOM_CALLS = ("lapack_", "Sharding", "SPMDFullToShardShape", "SPMDShardToFullShape")
"""Custom calls any stored program may make: LAPACK's (set up before any load, `_load`) and XLA's
own sharding markers. A program calling anything else is stored only where its `CachedProgram`
declares the kernel (`Kernels`, registered before a load): a kernel missing in the loading process
would crash it, not raise."""


def _serialise(compiled: Any, skeleton: Any, n_in: int, kernels: Kernels | None = None) -> bytes:
    from jax.experimental import serialize_executable

    unloaded = compiled._executable._unloaded_executable
    if (
        getattr(unloaded, "host_callbacks", None)
        or getattr(unloaded, "ordered_effects", None)
        or getattr(unloaded, "unordered_effects", None)
    ):
        raise ValueError("a program with host callbacks or effects is not stored")
    targets = set(re.findall(r'custom_call_target="([^"]+)"', compiled.as_text() or ""))
    declared = frozenset() if kernels is None else kernels.targets
    unknown = sorted(t for t in targets if not t.startswith(_SAFE_CUSTOM_CALLS) and t not in declared)
    if unknown:  # kernels registered lazily in a process (a native FFI target, ...) may be absent when loaded
        raise ValueError(f"a program calling {unknown} is not stored")
    exe, _, _ = serialize_executable.serialize(compiled)
    buf = io.BytesIO()
    skel = _dump_skeleton(skeleton)
    treedef: Any = jax.tree_util.tree_structure(skeleton, is_leaf=_is_slot)
    if jax.tree_util.tree_structure(_load_skeleton(skel), is_leaf=_is_slot) != treedef:
        raise ValueError("the output structure does not survive storing")  # (a later program would not trace)
    lapack = any(t.startswith("lapack_") for t in targets)
    custom = sorted(targets & declared)  # a preload (`_Session`) leaves these to their `CachedProgram`
    blob = {"format": FORMAT, "n_in": n_in, "exe": exe, "skeleton": skel, "lapack": lapack, "kernels": custom}
    pickle.dump(blob, buf)
    return buf.getvalue()


_BUILTIN = (type(None), bool, int, float, complex, str, bytes, tuple, list, dict, frozenset, set, type)


def _singleton_name(obj: Any) -> tuple[str, str] | None:
    """(module, name) where `obj` is a module-level instance of its class's module (a sentinel such
    as equinox's MISSING, compared by identity in pytree metadata), else None."""
    if isinstance(obj, _BUILTIN) or isinstance(obj, types.FunctionType):
        return None
    module = sys.modules.get(type(obj).__module__)
    if module is None:
        return None
    for name, value in vars(module).items():
        if value is obj:
            return module.__name__, name
    return None


class _SkeletonPickler(pickle.Pickler):
    def persistent_id(self, obj: Any) -> Any:
        return _singleton_name(obj)


class _SkeletonUnpickler(pickle.Unpickler):
    def persistent_load(self, pid: Any) -> Any:
        module, name = pid
        return getattr(sys.modules[module], name)


def _dump_skeleton(skeleton: Any) -> bytes:
    """An output skeleton's bytes, its module-level singletons stored by reference: pickled by
    value, equinox's MISSING (in every module's pytree metadata) came back as a new object, which
    pytree metadata compares unequal, and a program traced on a loaded program's outputs failed."""
    buf = io.BytesIO()
    _SkeletonPickler(buf).dump(skeleton)
    return buf.getvalue()


def _load_skeleton(data: bytes) -> Any:
    return _SkeletonUnpickler(io.BytesIO(data)).load()


def _load(path: Path, n_in: int) -> _Entry | None:
    """The entry stored at `path`, or None (absent, another layout, corrupt, not loadable)."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    return _from_bytes(data, n_in, path)


def _from_bytes(data: bytes, n_in: int | None, path: Path | None) -> _Entry | None:
    """The entry in `data` (None: not loadable). `n_in` None (a preload): any number of inputs,
    but no program calling custom kernels (their `CachedProgram` registers them first)."""
    from jax._src.lax import linalg
    from jax.experimental import serialize_executable

    try:
        blob = pickle.loads(data)
        if blob.get("format") != FORMAT or (n_in is not None and blob.get("n_in") != n_in):
            return None
        if n_in is None and blob["kernels"]:
            return None
        n_in = int(blob["n_in"])
        if blob["lapack"]:
            # LAPACK's kernels are set up when a program using them is lowered; a program loaded
            # without lowering needs them set up first (or it crashes at its first call). Only
            # then: it imports scipy.linalg (~0.15 s), which a lattice run does not need
            linalg.initialize_lapack()
        skeleton = _load_skeleton(blob["skeleton"])
        n_out = sum(1 for x in jax.tree_util.tree_leaves(skeleton, is_leaf=_is_slot) if _is_slot(x))
        in_tree = jax.tree_util.tree_structure((tuple(range(n_in)), {}))
        out_tree = jax.tree_util.tree_structure(list(range(n_out)))
        compiled = serialize_executable.deserialize_and_load(blob["exe"], in_tree, out_tree)
        return _Entry(compiled, skeleton, path, n_in)
    except Exception:  # noqa: BLE001 - any unreadable entry is a miss, never an error
        return None


def _store(path: Path, payload: bytes) -> None:
    """Write atomically (a temporary file renamed), ignoring a read-only or full disk."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        _evict_stale(path.parent)
        tmp = path.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp")
        tmp.write_bytes(payload)
        os.replace(tmp, path)
    except OSError:
        pass


@functools.cache
def _evict_stale(where: Path) -> None:
    """Remove, once per process and folder, files of other fingerprints not written for
    `STALE_DAYS` and temporary files over a day old (a process that died mid-write)."""
    mine = package_fingerprint()[:16]
    now = time.time()
    for p in where.iterdir():
        try:
            age_days = (now - p.stat().st_mtime) / 86400
            stale = p.suffix in (".prog", ".manifest") and not p.name.startswith(mine) and age_days > STALE_DAYS
            if stale or (p.suffix == ".tmp" and age_days > 1):
                p.unlink()
        except OSError:
            pass


class _Session:
    """This process's use of the disk cache, for the next one: the programs it read or stored, in
    order (not those calling custom kernels), kept in a manifest named after its first program's
    key. A later process whose first program has that key (the same fit, say) loads the rest in a
    thread from then on (`begin`): deserialising runs in XLA's threads without Python's lock
    (~10-45 ms a program, ~0.3 s for a fit's 32), beside the caller's own work, and `take` hands
    over what is loaded. A program the caller needs before the thread reaches it is loaded by the
    caller (`take` cancels it there)."""

    def __init__(self):
        self.lock = threading.Lock()
        self.manifest: Path | None = None
        self.known: list[str] = []  # the manifest read
        self.sequence: list[str] = []  # this process's
        self.pending: dict[Path, Any] = {}

    def begin(self, where: Path, key: str) -> None:
        with self.lock:
            if self.manifest is not None:
                return
            self.manifest = where / f"{package_fingerprint()[:16]}-{key}.manifest"
            if os.environ.get("DIFFLATTICE_PROGRAM_PRELOAD", "1") == "0":
                return
            try:
                self.known = [n for n in self.manifest.read_text().split("\n") if n.endswith(".prog")]
            except OSError:
                return
            from concurrent.futures import Future

            paths = [where / n for n in self.known if n != f"{package_fingerprint()[:16]}-{key}.prog"]
            self.pending = {p: Future() for p in paths}
            threading.Thread(target=self._preload, args=(paths,), daemon=True, name="program-preload").start()

    def _preload(self, paths: list[Path]) -> None:
        for p in paths:
            future = self.pending.get(p)
            if future is None or not future.set_running_or_notify_cancel():
                continue  # taken by the caller meanwhile
            entry = None
            try:
                entry = _from_bytes(p.read_bytes(), None, p)
            except BaseException:  # noqa: BLE001 - a file that is not there or not readable: the caller loads it
                entry = None
            future.set_result(entry)

    def take(self, path: Path) -> _Entry | None:
        """The preloaded entry of `path` (waiting if it is being loaded), or None (not preloaded,
        not reached yet, or not loadable)."""
        with self.lock:
            future = self.pending.pop(path, None)
        if future is None or future.cancel():
            return None
        return future.result()

    def record(self, path: Path) -> None:
        """Note a program read or stored; the manifest is rewritten where this process's order has
        left the one read."""
        with self.lock:
            self.sequence.append(path.name)
            if self.manifest is None or self.sequence == self.known[: len(self.sequence)]:
                return
            text = "\n".join(self.sequence) + "\n"
            where = self.manifest
        try:
            tmp = where.with_suffix(f".{os.getpid()}.{threading.get_ident()}.tmp")
            tmp.write_text(text)
            os.replace(tmp, where)
        except OSError:
            pass


_SESSION = _Session()
