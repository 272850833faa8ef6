"""pursuit-mj's simulator: layouts and scenes (layout, scene), physics in two fidelities
(physics, controller), the pursuit task (env, pz_env, evader, sensing, rewards), the
hand-made policies (heuristic, shield), evaluation, rendering and recording, and flight.

Importing the package imports nothing else: `pursuit_cli` checks that mujoco can start
before any module here loads it.
"""

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("pursuit-mj")  # the installed distribution's, as pyproject.toml gives it
except _metadata.PackageNotFoundError:  # run from a source tree that was never installed
    __version__ = "unknown"
