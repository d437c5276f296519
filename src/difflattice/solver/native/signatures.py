"""The native kernels' FFI signatures, declared once and called by name.

XLA's FFI passes buffers by position. Each target's buffers are named here once, in the order of
its C++ handler's parameters (`lattice.cc`, `volume.cc`; tests/core/test_native_signatures.py
reads those parameter lists and compares them with these names), and every call site hands its
buffers over by name: `Signature.call` puts them in order, refuses a missing or unknown name,
derives the in-place aliases from the names and returns the results by name.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Mapping
from typing import Any

import jax

__all__ = ["ADJOINT_CHUNK", "LAYERED", "LEAPFROG", "SIGNATURES", "Signature", "VOLUME", "VOLUME_LAYERED"]


@dataclasses.dataclass(frozen=True)
class Signature:
    """One FFI target: its buffer arguments and results by name (C++ order), the optional ones
    after them (all given or none), and which result is written in place of which argument."""

    target: str
    args: tuple[str, ...]
    rets: tuple[str, ...]
    aliases: tuple[str, ...]  # names that are both an argument and a result: the result reuses the buffer
    optional_args: tuple[str, ...] = ()
    optional_rets: tuple[str, ...] = ()
    handler: str = ""  # the C++ handler function (for the signature test)

    def call(
        self,
        args: Mapping[str, Any],
        rets: Mapping[str, jax.ShapeDtypeStruct],
        aliased: Collection[str] | None = None,
        /,
        **attrs: Any,
    ) -> dict[str, jax.Array]:
        """Call the target with `args` (name -> array) for results `rets` (name -> shape and
        dtype); `aliased` limits the in-place results to these names (default: every alias
        present); `attrs` are the handler's attributes (by name, as XLA passes them)."""
        arg_names = self._names(args, self.args, self.optional_args, "argument")
        ret_names = self._names(rets, self.rets, self.optional_rets, "result")
        wanted = set(self.aliases if aliased is None else aliased)
        aliases = {
            arg_names.index(n): ret_names.index(n)
            for n in self.aliases
            if n in wanted and n in arg_names and n in ret_names
        }
        out = jax.ffi.ffi_call(
            self.target, [rets[n] for n in ret_names], input_output_aliases=aliases, vmap_method="sequential"
        )(*(args[n] for n in arg_names), **attrs)
        return dict(zip(ret_names, out))

    def _names(self, given: Mapping[str, Any], required: tuple[str, ...], optional: tuple[str, ...], what: str):
        unknown = set(given) - set(required) - set(optional)
        missing = [n for n in required if n not in given]
        if unknown or missing:
            raise ValueError(
                f"{self.target}: {what}s {sorted(unknown)} are not in its signature and {missing} are missing "
                f"(signature: {', '.join(required)}; optional: {', '.join(optional) or 'none'})"
            )
        extra = [n for n in optional if n in given]
        if extra and len(extra) != len(optional):
            raise ValueError(f"{self.target}: the optional {what}s {list(optional)} go together; got {extra}")
        return list(required) + extra


_STATS = ("ph_re", "ph_im", "p_max", "p_sq", "arrival")

LEAPFROG = Signature(
    "difflattice_leapfrog",
    args=(
        *("p", "pp", "K", "bx", "by", "qs", "keep", "sponge", "my_lo", "my_hi"),
        *("src_cells", "src_hard", "src_vals", "rec_cells", "zero_cells", "ph_cells", "ph_cos", "ph_sin"),
        *_STATS,
        "n0",
    ),
    rets=("p", "pp", "rec", *_STATS),
    aliases=("p", "pp", *_STATS, "rq0", "rq1"),
    optional_args=("rq0", "rq1", "relax"),
    optional_rets=("rq0", "rq1"),
    handler="leapfrog_impl",
)
"""The 2-D and rz leapfrog (`leapfrog.h`); with rq0, rq1, relax: air absorption's memory fields."""

LAYERED = dataclasses.replace(
    LEAPFROG,
    target="difflattice_layered",
    args=(*LEAPFROG.args, "lp", "lw", "lc", "boxes", "axc", "bxc", "axf", "bxf", "ayc", "byc", "ayf", "byf")
    + ("rad_decay", "rad_drive"),
    rets=(*LEAPFROG.rets, "lp", "lw", "lc"),
    aliases=(*LEAPFROG.aliases, "lp", "lw", "lc"),
    handler="layered_impl",
)
"""The leapfrog with PML layers (`layers.h`): the layers' packed fields, boxes and factor profiles."""

ADJOINT_CHUNK = Signature(
    "difflattice_adjoint_chunk",
    args=(
        *("p_end", "pp_end", "x", "h", "K", "bx", "by", "ml", "mh", "vol", "area"),
        *("src_cells", "src_hard", "src_vals", "inj_cells", "inj_vals", "rec_cells", "zero_cells", "dK", "dbx", "dby"),
    ),
    rets=("x", "h", "rec", "dK", "dbx", "dby"),
    aliases=("x", "h", "dK", "dbx", "dby"),
    handler="adjoint_chunk_impl",
)
"""The lattice adjoint's backward pass with the coefficients' cotangents (`adjoint.h`)."""

VOLUME = Signature(
    "difflattice_volume",
    args=(
        *("p", "pp", "K", "bx", "by", "bz", "keep", "sponge", "src_cells", "src_hard", "src_vals", "rec_cells"),
        *("ph_cells", "ph_cos", "ph_sin", *_STATS, "n0"),
    ),
    rets=("p", "pp", "rec", *_STATS),
    aliases=("p", "pp", *_STATS),
    handler="volume_impl",
)
"""The 3-D leapfrog (`volume.h`)."""

VOLUME_LAYERED = dataclasses.replace(
    VOLUME,
    target="difflattice_volume_layered",
    args=(*VOLUME.args, "lp", "lw", "boxes", *(f"f{i}" for i in range(12))),
    rets=(*VOLUME.rets, "lp", "lw"),
    aliases=(*VOLUME.aliases, "lp", "lw"),
    handler="volume_layered_impl",
)
"""The 3-D leapfrog with PML layers: packed fields, boxes and the 12 factor profiles f0..f11
(a, b at cells and faces, per axis: x cell a, x cell b, x face a, x face b, then y, z)."""

SIGNATURES = (LEAPFROG, LAYERED, ADJOINT_CHUNK, VOLUME, VOLUME_LAYERED)
