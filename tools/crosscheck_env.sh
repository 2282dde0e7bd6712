#!/usr/bin/env bash
# Build the cross-check's own environment (.venv-crosscheck, git-ignored): a CPU torch, gsplat's
# pure-PyTorch reference (no CUDA extension is built or loaded: tools/crosscheck.py imports only
# gsplat.cuda._torch_impl) and seuwgpu from this tree. Kept apart from the package's dependencies
# so that ./dev test never installs torch. Usage: tools/crosscheck_env.sh [python]
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${1:-python3.11}"
VENV=.venv-crosscheck
TORCH=2.13.0
GSPLAT=1.5.3
[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
"$VENV/bin/pip" install -q --upgrade pip
# the CPU wheel: pin torch exactly so pip never resolves a newer (CUDA) build
"$VENV/bin/pip" install -q "torch==$TORCH"
# gsplat's declared dependencies are ninja (for its CUDA JIT, unused here), jaxtyping, rich, torch
"$VENV/bin/pip" install -q --no-deps "gsplat==$GSPLAT"
"$VENV/bin/pip" install -q jaxtyping typing_extensions
"$VENV/bin/pip" install -q -c constraints.txt -e .
"$VENV/bin/python" - <<'PY'
import gsplat, torch
print("torch", torch.__version__, "gsplat", gsplat.__version__, "cuda", torch.cuda.is_available())
PY
