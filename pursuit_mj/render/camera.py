"""Which camera a render looks through: a fixed scene camera ('top', 'angled') or one following a drone.

`CameraSpec.parse('follow:pursuer_0', model, drone_names)` checks the name against the scene
before any frame is drawn; `apply` points an MjvCamera for the current frame.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

FOLLOW_PREFIX = "follow:"
FOLLOW_DISTANCE = 2.0  # m from the drone
FOLLOW_ELEVATION = -60.0  # deg, looking down: steep enough that a 1.2 m obstacle hides the drone only within 0.4 m of it (at -38 deg, 0.9 m)
FOLLOW_AZIMUTH = 90.0  # deg: camera south of the drone, looking north (+y)


def fixed_camera_names(model: mujoco.MjModel) -> list[str]:
    return [model.camera(i).name for i in range(model.ncam)]


@dataclasses.dataclass(frozen=True)
class CameraSpec:
    """A fixed model camera (`name`) or a free camera following drone `follow` (index into drone order)."""

    text: str
    name: str | None = None
    follow: int | None = None

    @staticmethod
    def parse(text: str, model: mujoco.MjModel, drone_names: list[str], source: str = "--camera") -> "CameraSpec":
        if text.startswith(FOLLOW_PREFIX):
            drone = text[len(FOLLOW_PREFIX):]
            if drone not in drone_names:
                raise ValueError(f"{source} {text!r}: no drone named {drone!r} (drones: {', '.join(drone_names)})")
            return CameraSpec(text, follow=drone_names.index(drone))
        names = fixed_camera_names(model)
        if text not in names:
            options = names + [f"{FOLLOW_PREFIX}{drone_names[0]}"] if drone_names else names
            raise ValueError(f"{source} {text!r}: no such camera (choose from: {', '.join(options)}, or follow:<drone>)")
        return CameraSpec(text, name=text)

    def apply(self, cam: mujoco.MjvCamera, model: mujoco.MjModel, drone_pos: np.ndarray) -> None:
        """Point `cam` for this frame; drone_pos (D, 3) m world, drones in scene order."""
        if self.follow is None:
            cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            cam.fixedcamid = model.camera(self.name).id
            return
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = drone_pos[self.follow]
        cam.distance = FOLLOW_DISTANCE
        cam.elevation = FOLLOW_ELEVATION
        cam.azimuth = FOLLOW_AZIMUTH
