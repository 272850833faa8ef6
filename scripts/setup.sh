#!/usr/bin/env bash
# Creates .venv (Python 3.11) and installs pursuit-mj with the versions pinned in pyproject.toml.
# Safe to run again: it reinstalls only when pyproject.toml changed since the last install.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3.11}
if ! command -v "$PY" >/dev/null 2>&1; then
  if [ -n "${PYTHON:-}" ]; then
    echo "setup.sh: PYTHON=$PYTHON: no such command" >&2
    exit 2
  fi
  PY=python3  # python3.11 not on PATH: python3, if it is 3.11 (checked below)
fi
NEEDED=3.11  # pyproject.toml's requires-python
version_of() {  # "3.11" for a Python executable, "" when it does not run
  "$1" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null || true
}
if [ -x .venv/bin/python ]; then
  found=$(version_of .venv/bin/python)
  if [ "$found" != "$NEEDED" ]; then
    echo "setup.sh: .venv was made with Python ${found:-that does not run}; pursuit-mj needs Python $NEEDED:" \
      "delete .venv and run again (with python$NEEDED on PATH, or PYTHON=/path/to/python$NEEDED)" >&2
    exit 2
  fi
else
  found=$(version_of "$PY")
  if [ "$found" != "$NEEDED" ]; then
    echo "setup.sh: $PY is Python ${found:-that does not run}; pursuit-mj needs Python $NEEDED" \
      "(install python$NEEDED, or run with PYTHON=/path/to/python$NEEDED)" >&2
    exit 2
  fi
  "$PY" -m venv .venv
fi
stamp=.venv/.pursuit-mj-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  .venv/bin/python -m pip install --quiet --upgrade pip
  # torch==2.13.0 is pinned in pyproject.toml and installed first, from TORCH_INDEX_URL if set:
  # plain PyPI serves Linux the CUDA build (GBs); https://download.pytorch.org/whl/cpu the CPU one.
  .venv/bin/python -m pip install --quiet ${TORCH_INDEX_URL:+--index-url "$TORCH_INDEX_URL"} "torch==2.13.0"
  .venv/bin/python -m pip install --quiet -e ".[test]"
  touch "$stamp"
fi
