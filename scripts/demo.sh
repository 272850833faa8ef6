#!/usr/bin/env bash
# The main job on built-in defaults: sets up on first use, then runs `pursuit-mj demo`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export MUJOCO_GL=${MUJOCO_GL:-egl}
exec .venv/bin/pursuit-mj demo "$@"
