#!/usr/bin/env bash
# The test suite: sets up on first use, then runs pytest with a worker per core
# (tests/conftest.py pins each worker to its core; `bash scripts/test.sh -n 0` runs them in one process).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# the offscreen OpenGL the renderer would pick here (EGL, else OSMesa), found once for every worker
export MUJOCO_GL=${MUJOCO_GL:-$(.venv/bin/python -c "from pursuit_mj.render.gl import choose_backend; print(choose_backend())" 2>/dev/null || echo egl)}
exec .venv/bin/python -m pytest -n auto --dist worksteal "$@"
