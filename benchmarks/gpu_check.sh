#!/usr/bin/env bash
# One command on a machine with a GPU (under 8 minutes): MLUPS and the fraction of the card's
# bandwidth bound for 2-D 4096^2 and 3-D 512^3 (7-, 19- and 25-point), then the GPU's probes against
# the CPU path on small grids. Usage, from the repository root:
#     bash benchmarks/gpu_check.sh [--quick] [--json out.json]
# Needs a JAX with CUDA (pip install -U "jax[cuda12]" or "jax[cuda13]") in the Python it runs ($PYTHON, default
# .venv/bin/python or python3).
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-}"
if [ -z "$PY" ]; then
    if [ -x .venv/bin/python ]; then PY=.venv/bin/python; else PY=python3; fi
fi
export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}"
export XLA_PYTHON_CLIENT_PREALLOCATE=false
"$PY" -c 'import jax; d = jax.devices()[0]; print("jax", jax.__version__, d.platform, getattr(d, "device_kind", ""))'
exec timeout 480 "$PY" benchmarks/gpu_check.py "$@"
