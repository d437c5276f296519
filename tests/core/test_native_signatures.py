"""The native kernels' FFI signatures are declared once (`solver.native.signatures`) and match
the C++ handlers' parameter lists by name: XLA passes buffers by position, so a Python list out of
step with the C++ one would hand the wrong arrays to the kernel. The handlers' parameters are read
from the C++ sources (the compiler already holds each handler to its `Bind()` chain)."""

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

from difflattice.solver.native import signatures
from difflattice.solver.native.signatures import LEAPFROG, SIGNATURES

NATIVE = Path(signatures.__file__).resolve().parent


def _handler_params(name: str) -> dict[str, list[str]]:
    text = "\n".join(p.read_text() for p in sorted(NATIVE.glob("*.cc")))
    m = re.search(r"ffi::Error\s+" + name + r"\s*\(([^)]*)\)\s*\{", text)
    assert m, f"handler {name} not found in {NATIVE}/*.cc"
    out: dict[str, list[str]] = {"args": [], "rets": [], "optional_args": [], "optional_rets": []}
    for param in (p.strip() for p in m.group(1).split(",")):
        *typ, pname = param.split()
        t = " ".join(typ)
        if t == "ffi::AnyBuffer":
            out["args"].append(pname)
        elif t == "ffi::Result<ffi::AnyBuffer>":
            out["rets"].append(pname.removesuffix("_o"))
        elif t == "Opt":
            out["optional_args"].append(pname)
        elif t == "OptRet":
            out["optional_rets"].append(pname.removesuffix("_o"))
    return out


@pytest.mark.parametrize("sig", SIGNATURES, ids=[s.target for s in SIGNATURES])
def test_signature_matches_the_cpp_handler_by_name(sig):
    cpp = _handler_params(sig.handler)
    assert list(sig.args) == cpp["args"]
    assert list(sig.rets) == cpp["rets"]
    assert list(sig.optional_args) == cpp["optional_args"]
    assert list(sig.optional_rets) == cpp["optional_rets"]
    # every alias is both an argument and a result
    names_in = set(sig.args) | set(sig.optional_args)
    names_out = set(sig.rets) | set(sig.optional_rets)
    assert set(sig.aliases) <= names_in & names_out


def test_a_call_with_a_missing_or_unknown_buffer_is_refused_by_name():
    f32 = jax.ShapeDtypeStruct((2, 2), jnp.float32)
    args = dict.fromkeys(LEAPFROG.args, jnp.zeros((2, 2), jnp.float32))
    rets = dict.fromkeys(LEAPFROG.rets, f32)
    bad = {k: v for k, v in args.items() if k != "sponge"} | {"spnoge": args["sponge"]}
    with pytest.raises(ValueError, match=r"\['spnoge'\] are not in its signature and \['sponge'\] are missing"):
        LEAPFROG.call(bad, rets)
    with pytest.raises(ValueError, match="go together"):
        LEAPFROG.call(args | {"rq0": args["p"]}, rets)
