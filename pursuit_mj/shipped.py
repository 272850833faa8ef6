"""Where the files that ship beside the code are: models/, configs/ and pretrained/.

In a checkout they are the repository's top-level folders (DESIGN.md section 4).
pursuit_mj/assets/ holds a symlink to each, through which a wheel (`pip install .`, not
editable) copies them into the installed package, so the same path serves both. Where a
checkout was made without symlinks (Windows git's default), the top-level folder is used.
"""

from __future__ import annotations

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
REPO_ROOT = PACKAGE_DIR.parent  # the checkout; in an installed wheel, site-packages
SHIPPED = ("models", "configs", "pretrained")


def shipped_dir(name: str) -> Path:
    """The folder `name` (one of SHIPPED), resolved: /checkout/configs in a checkout,
    .../site-packages/pursuit_mj/assets/configs in an installed wheel."""
    if name not in SHIPPED:
        raise ValueError(f"shipped_dir: {name!r} is not one of {SHIPPED}")
    packaged = PACKAGE_DIR / "assets" / name
    return packaged.resolve() if packaged.is_dir() else REPO_ROOT / name
