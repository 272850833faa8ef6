#!/usr/bin/env bash
# The test suite: sets up on first use, then runs pytest with a worker per core
# (tests/conftest.py pins each worker to its core; `bash scripts/test.sh -n 0` runs them in one process).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export MUJOCO_GL=${MUJOCO_GL:-egl}
exec .venv/bin/python -m pytest -n auto --dist worksteal "$@"
