"""Compile the native kernels for the machine they run on, cache the library, register its XLA
FFI targets.

The C++ source ships as package data (`lattice.cc`, `volume.cc` and the headers they include, two
translation units). At first use it is compiled with the C++
compiler found (`$CXX`, else `c++`, `g++`, `clang++`) for this processor (`-march=native`: not
portable, hence compiled where it runs) against XLA's FFI headers from the installed jaxlib, and
cached in ``$DIFFLATTICE_NATIVE_CACHE`` (default ``~/.cache/difflattice/native``) under a hash of
the source, the flags, the compiler, jaxlib and the processor, so a later process loads it in
milliseconds. Without a compiler (or with ``DIFFLATTICE_NATIVE=0``) `load()` returns the reason
and the solver runs its JAX loop; the reason is printed once per process, on one line.

The build (~20-60 s, once per machine and version) prints a line to stderr when it starts and
when it ends; ``python -m difflattice.solver.native`` runs it ahead of time (after an
install, in an image build) and prints the cached library's path.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

SOURCE = Path(__file__).with_name("lattice.cc")
# the translation units of the library: the 2-D and rz kernels, the 3-D kernel (volume.cc)
SOURCES = (SOURCE, SOURCE.with_name("volume.cc"))
TARGETS = {
    "difflattice_leapfrog": "DifflatticeLeapfrog",
    "difflattice_layered": "DifflatticeLayered",
    "difflattice_adjoint_chunk": "DifflatticeAdjointChunk",
    "difflattice_volume": "DifflatticeVolume",
    "difflattice_volume_layered": "DifflatticeVolumeLayered",
}
COMPILE_TIMEOUT_S = 300
GENERIC_NOTE = "generic.txt"  # beside a library built without -march=native: why


@dataclass(frozen=True)
class Library:
    """A loaded kernel library whose FFI targets are registered with JAX (CPU platform)."""

    path: Path
    handle: ctypes.CDLL


def cache_dir() -> Path:
    where = os.environ.get("DIFFLATTICE_NATIVE_CACHE")
    return Path(where) if where else Path.home() / ".cache" / "difflattice" / "native"


def find_compiler() -> str | None:
    for name in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def _flags(include_dir: str, native_arch: bool) -> list[str]:
    flags = [
        "-O3",
        "-std=c++17",
        "-shared",
        "-fPIC",
        "-pthread",
        "-fno-math-errno",
        # XLA's CPU backend contracts a * b + c into FMAs: do the same, so both agree closely
        "-ffp-contract=fast",
        "-I",
        include_dir,
    ]
    if native_arch:
        flags.append("-march=native")
        if platform.machine().lower() in ("x86_64", "amd64"):
            # the width also for the kernels' explicit vector loops (stencil.h: the rz ring form)
            flags += [f"-mprefer-vector-width={vector_bits()}", f"-DDL_VECTOR_BITS={vector_bits()}"]
    return flags


def vector_bits() -> int:
    """The vector width the compiler may use on x86 (``DIFFLATTICE_NATIVE_VECTOR_BITS`` overrides):
    512 on AMD Zen 5 and later (family 0x1A: full-width AVX-512 units; the homogeneous 840x630
    leapfrog ran ~20 % faster per core with 512-bit vectors than with 256-bit ones, single thread,
    CPU time), 256 elsewhere (Zen 4 splits 512-bit operations in two, and an earlier measurement
    found them 8 % slower there; Intel cores lower their clock on wide vectors; AVX2 machines have
    nothing wider)."""
    env = os.environ.get("DIFFLATTICE_NATIVE_VECTOR_BITS")
    if env in ("128", "256", "512"):
        return int(env)
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return 256
    vendor = family = None
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "vendor_id" and vendor is None:
            vendor = value.strip()
        elif key.strip() == "cpu family" and family is None:
            family = value.strip()
    wide = vendor == "AuthenticAMD" and family is not None and family.isdigit() and int(family) >= 0x1A
    return 512 if wide and " avx512f" in text else 256


def _processor_id() -> str:
    """What -march=native depends on: the CPU model and its feature flags."""
    try:
        text = Path("/proc/cpuinfo").read_text()
        keep = [ln for ln in text.splitlines() if ln.startswith(("model name", "flags", "Features", "CPU part"))]
        return "\n".join(sorted(set(keep)))
    except OSError:
        return platform.processor() + platform.machine()


def _compiler_version(cxx: str) -> str:
    try:
        return subprocess.run([cxx, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return ""


class _Transient(str):
    """A build failure worth retrying in the next process (a timeout on a busy machine)."""


def _compile(cxx: str, out: Path, include_dir: str) -> str | None:
    """Build the library at `out` (atomically); None on success, else the compiler's complaint.

    Only a compiler that REJECTS -march=native gets the generic build (slower kernels): it is
    said on stderr and recorded in ``generic.txt`` beside the library, which every later process
    reports. A timeout or a missing compiler is not a reason for a generic build (returned as
    `_Transient`: the next process tries again)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    last = ""
    for native_arch in (True, False):  # a compiler without -march=native: a generic build
        fd, tmp = tempfile.mkstemp(suffix=".so", dir=out.parent)
        os.close(fd)
        cmd = [cxx, *_flags(include_dir, native_arch), *map(str, SOURCES), "-o", tmp]
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=COMPILE_TIMEOUT_S)
        except (OSError, subprocess.SubprocessError) as e:
            Path(tmp).unlink(missing_ok=True)
            return _Transient(f"{e} (a busy machine? the next process tries again)")
        if r.returncode == 0:
            os.replace(tmp, out)  # concurrent builders: the last complete library wins
            if not native_arch:
                note = f"built without -march=native (slower kernels): the native build failed: {last}"
                print(f"difflattice: {note}", file=sys.stderr, flush=True)
                out.with_name(GENERIC_NOTE).write_text(note + "\n")
            return None
        lines = (r.stderr or r.stdout).strip().splitlines()
        errors = [ln for ln in lines if "error" in ln]
        last = (errors or lines or [f"exit {r.returncode}"])[0][:300]
        Path(tmp).unlink(missing_ok=True)
    return last


@functools.cache
def load() -> Library | str:
    """The registered kernel library, or the reason it is not available (printed once)."""
    reason = _load()
    if isinstance(reason, str):
        print(f"difflattice: native CPU kernels unavailable ({reason}); using the JAX loop", file=sys.stderr)
    return reason


def _load() -> Library | str:
    if os.environ.get("DIFFLATTICE_NATIVE", "1") == "0":
        return "DIFFLATTICE_NATIVE=0"
    import jax
    import jaxlib

    try:
        include_dir = jax.ffi.include_dir()
    except AttributeError:
        return f"jax {jax.__version__} has no jax.ffi"
    cxx = find_compiler()
    if cxx is None:
        return "no C++ compiler found: install g++ or clang++, or set CXX"
    key = hashlib.sha256()
    for part in (
        *(src.read_bytes() for src in SOURCES),
        *(h.read_bytes() for h in sorted(SOURCE.parent.glob("*.h"))),  # their headers
        " ".join(_flags(include_dir, True)).encode(),
        _compiler_version(cxx).encode(),
        jaxlib.__version__.encode(),
        _processor_id().encode(),
    ):
        key.update(part)
        key.update(b"\0")
    path = cache_dir() / key.hexdigest()[:20] / "liblattice.so"
    failed = path.with_name("failed.txt")  # a failed build is not retried in every new process
    if failed.exists():
        return failed.read_text().strip() + f" (delete {failed.parent} to retry)"
    if not path.exists():
        # the one slow start of a machine: say so while it happens (stderr, so piped outputs stay clean)
        print(
            f"difflattice: compiling the native CPU kernels for this machine with {Path(cxx).name} "
            f"(once per machine and version, ~20-60 s; cached in {path.parent}) ...",
            file=sys.stderr,
            flush=True,
        )
        t0 = time.perf_counter()
        err = _compile(cxx, path, include_dir)
        if err is None:
            print(
                f"difflattice: native kernels compiled in {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True
            )
        if err is not None:
            reason = f"compiling {', '.join(s.name for s in SOURCES)} with {cxx} failed: {err}"
            if not isinstance(err, _Transient):
                try:
                    failed.write_text(reason + "\n")
                except OSError:
                    pass
            return reason
    generic = path.with_name(GENERIC_NOTE)
    if generic.exists():
        print(f"difflattice: {generic.read_text().strip()} (delete {path.parent} to retry)", file=sys.stderr)
    try:
        handle = ctypes.cdll.LoadLibrary(str(path))
        for target, symbol in TARGETS.items():
            jax.ffi.register_ffi_target(target, jax.ffi.pycapsule(getattr(handle, symbol)), platform="cpu")
    except (OSError, AttributeError, ValueError) as e:
        return f"loading {path} failed: {e}"
    return Library(path, handle)


def main(argv=None) -> int:
    """Build the kernels ahead of time (e.g. right after installing, or in an image build):
    ``python -m difflattice.solver.native``. Prints the library's path, or the reason it
    is not available (exit status 1)."""
    del argv
    lib = load()
    if isinstance(lib, str):
        return 1
    print(lib.path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
