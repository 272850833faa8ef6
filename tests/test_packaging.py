"""A wheel (`pip install .`, not editable) carries what the code reads beside it: the drone
model, the built-in layouts and presets, and the pretrained policy (pursuit_mj/shipped.py)."""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SHIPPED = ("models", "configs", "pretrained")


def build_and_unpack_wheel(tmp: Path) -> Path:
    """The wheel of a copy of this checkout (the build writes build/ and egg-info beside the
    sources: not into the checkout under test), unpacked as pip installs a pure-Python wheel."""
    src = tmp / "src"
    shutil.copytree(REPO, src, symlinks=True, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "*.egg-info", "__pycache__", ".pytest_cache", "runs", "renders", "plots", "out", "finals",
        "flights", "*.rrd"))  # what .gitignore leaves out: outputs, not sources
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp / "dist"), str(src)],
                           capture_output=True, text=True, timeout=300)
    assert built.returncode == 0, built.stdout + built.stderr
    (wheel,) = (tmp / "dist").glob("pursuit_mj-*.whl")
    site = tmp / "site"
    with zipfile.ZipFile(wheel) as z:
        z.extractall(site)
    return site


def test_a_wheel_carries_the_shipped_files_and_runs_away_from_any_checkout(tmp_path):
    site = build_and_unpack_wheel(tmp_path)
    assets = site / "pursuit_mj" / "assets"
    for name in SHIPPED:
        in_repo = sorted(str(p.relative_to(REPO / name)) for p in (REPO / name).rglob("*") if p.is_file())
        in_wheel = sorted(str(p.relative_to(assets / name)) for p in (assets / name).rglob("*") if p.is_file())
        assert in_wheel == in_repo, name
        assert not (assets / name).is_symlink()  # copies, not links back into a checkout

    # run from another folder with only the unpacked wheel (and the dependencies) importable:
    # a built-in layout, a task preset, the drone model and the demo's shipped policy
    script = (
        "import pursuit_mj, sys\n"
        f"assert pursuit_mj.__file__.startswith({str(site)!r}), pursuit_mj.__file__\n"
        "from pursuit_cli import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    for argv in (["layout", "check", "3"], ["config", "--task", "hard"],
                 ["demo", "--episodes", "1", "--worlds", "1", "--layouts", "2", "--fidelity", "point", "--no-heuristic"]):
        out = subprocess.run([sys.executable, "-c", script, *argv], cwd=elsewhere, env=env, capture_output=True,
                             text=True, timeout=300)
        assert out.returncode == 0, f"{argv}: {out.stdout}{out.stderr}"
    shipped = assets / "pretrained"
    assert f"= {shipped / 'pursuers.pt'} (the small policy shipped" in out.stderr
    assert f"{shipped / 'README.md'} gives the command that made it" in out.stderr
    assert "bel2e+shield" in out.stdout  # the table


def test_the_package_says_its_version_as_the_project_file_gives_it():
    import tomllib
    from pathlib import Path

    import pursuit_mj

    project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
    assert pursuit_mj.__version__ == project["version"]


def _setup_copy(tmp: Path) -> Path:
    """scripts/setup.sh and pyproject.toml in a folder of their own, as a fresh checkout has them."""
    (tmp / "scripts").mkdir(parents=True)
    shutil.copy(REPO / "scripts" / "setup.sh", tmp / "scripts" / "setup.sh")
    shutil.copy(REPO / "pyproject.toml", tmp / "pyproject.toml")
    return tmp


def _fake_python(path: Path, version: str) -> Path:
    """An executable that answers every call as a Python of `version` would answer a version query, and
    records that it was asked anything else (creating a venv, installing)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'#!/bin/sh\ncase "$*" in *version_info*) echo {version} ;; *) echo "$*" >> "{path}.calls" ;; esac\n')
    path.chmod(0o755)
    return path


def test_setup_refuses_a_python_other_than_3_11_before_making_or_installing_anything(tmp_path):
    """On a machine whose python3 is 3.12 (Ubuntu 24.04) setup.sh made .venv with it, downloaded torch into it,
    then failed in pip ('requires a different Python'); installing 3.11 afterwards did not help, since the
    3.12 .venv stayed. It now says at once which Python it found and what to do, and touches nothing."""
    repo = _setup_copy(tmp_path / "repo")
    fake = _fake_python(tmp_path / "bin" / "python3.12", "3.12")
    out = subprocess.run(["bash", "scripts/setup.sh"], cwd=repo, env={**os.environ, "PYTHON": str(fake)},
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stdout + out.stderr
    assert f"setup.sh: {fake} is Python 3.12; pursuit-mj needs Python 3.11" in out.stderr
    assert not (repo / ".venv").exists() and not Path(f"{fake}.calls").exists()


def test_setup_refuses_a_venv_made_by_another_python_naming_it_and_the_way_out(tmp_path):
    repo = _setup_copy(tmp_path / "repo")
    _fake_python(repo / ".venv" / "bin" / "python", "3.12")
    out = subprocess.run(["bash", "scripts/setup.sh"], cwd=repo, env={**os.environ, "PYTHON": sys.executable},
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stdout + out.stderr
    assert ".venv was made with Python 3.12; pursuit-mj needs Python 3.11: delete .venv" in out.stderr
    assert not (repo / ".venv" / "bin" / "python.calls").exists()  # nothing installed into it


def test_setup_refuses_a_PYTHON_that_is_not_there_instead_of_taking_python3(tmp_path):
    repo = _setup_copy(tmp_path / "repo")
    out = subprocess.run(["bash", "scripts/setup.sh"], cwd=repo, env={**os.environ, "PYTHON": str(tmp_path / "python3.11")},
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stdout + out.stderr
    assert f"PYTHON={tmp_path / 'python3.11'}: no such command" in out.stderr and not (repo / ".venv").exists()
