#!/usr/bin/env bash
# The test suite: sets up on first use, then runs pytest with two workers per core on small machines
# (tests/conftest.py pins each worker to a core; `bash scripts/test.sh -n 0` runs them in one process).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# the offscreen OpenGL the renderer would pick here (EGL, else OSMesa), found once for every worker
export MUJOCO_GL=${MUJOCO_GL:-$(.venv/bin/python -c "from pursuit_mj.render.gl import choose_backend; print(choose_backend())" 2>/dev/null || echo egl)}
# Part of the suite waits (virtual Crazyflies over UDP, subprocesses, files synced): a second
# worker on a core runs while the first waits. On 2 cores 4 workers took 149-160 s against 206-237 s for a
# set of the slowest files (2026-12-07). Up to two workers more than cores; a later -n given to this script wins.
cores=$(.venv/bin/python -c "import os; print(len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else os.cpu_count() or 1)")
exec .venv/bin/python -m pytest -n $(( cores + (cores < 2 ? cores : 2) )) --dist worksteal "$@"
