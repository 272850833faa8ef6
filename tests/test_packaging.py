"""A wheel (`pip install .`, not editable) carries what the code reads beside it: the drone
model, the built-in layouts and presets, and the pretrained policy (pursuit_mj/shipped.py)."""

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def installed_wheel(tmp_path_factory) -> Path:
    """The wheel built from this checkout, unpacked as pip installs a pure-Python wheel."""
    tmp = tmp_path_factory.mktemp("wheel")
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp / "dist"), str(REPO)],
                           capture_output=True, text=True, timeout=300)
    assert built.returncode == 0, built.stdout + built.stderr
    (wheel,) = (tmp / "dist").glob("pursuit_mj-*.whl")
    site = tmp / "site"
    with zipfile.ZipFile(wheel) as z:
        z.extractall(site)
    return site


def test_the_wheel_holds_every_shipped_file(installed_wheel):
    assets = installed_wheel / "pursuit_mj" / "assets"
    for name in ("models", "configs", "pretrained"):
        in_repo = sorted(str(p.relative_to(REPO / name)) for p in (REPO / name).rglob("*") if p.is_file())
        in_wheel = sorted(str(p.relative_to(assets / name)) for p in (assets / name).rglob("*") if p.is_file())
        assert in_wheel == in_repo, name
        assert not (assets / name).is_symlink()  # copies, not links back into a checkout


def test_the_installed_package_runs_away_from_any_checkout(installed_wheel, tmp_path):
    """Run from another folder with only the unpacked wheel (and the dependencies) importable:
    a built-in layout and task preset, a train preset, the drone model and the demo's policy."""
    script = (
        "import pursuit_mj, sys\n"
        f"assert pursuit_mj.__file__.startswith({str(installed_wheel)!r}), pursuit_mj.__file__\n"
        "from pursuit_cli import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(installed_wheel), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    for argv in (["layout", "check", "3"], ["config", "--task", "hard"],
                 ["demo", "--episodes", "1", "--worlds", "1", "--layouts", "2", "--fidelity", "point", "--no-heuristic"]):
        out = subprocess.run([sys.executable, "-c", script, *argv], cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=300)
        assert out.returncode == 0, f"{argv}: {out.stdout}{out.stderr}"
    shipped = installed_wheel / "pursuit_mj" / "assets" / "pretrained"
    assert f"= {shipped / 'pursuers.pt'} (the small policy shipped" in out.stderr
    assert f"{shipped / 'README.md'} gives the command that made it" in out.stderr
    assert "belhs+shield" in out.stdout  # the table
