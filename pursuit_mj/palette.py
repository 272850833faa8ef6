"""The colours every picture of a chase shares: 3D frames, layout maps and their keys.

RGBA tuples in 0-1. The MuJoCo scene, the render overlays and their colour key, and the
matplotlib layout previews all take their colours from here, so a pursuer, an evader or a
random obstacle looks the same in each.
"""

from __future__ import annotations

ROLE_RGBA = {"pursuer": (0.15, 0.45, 0.95, 1.0), "evader": (0.95, 0.25, 0.15, 1.0)}
# obstacles by origin: drawn in the layout file, or placed at random for one episode
OBSTACLE_RGBA = {"fixed": (0.42, 0.38, 0.34, 1.0), "random": (0.82, 0.54, 0.18, 1.0)}
BORDER_RGBA = (0.17, 0.18, 0.2, 1.0)
FLOOR_RGB = ((0.92, 0.92, 0.9), (0.85, 0.85, 0.83))  # the two squares of the floor's checker texture


def over_floor(rgba: tuple) -> tuple[float, float, float, float]:
    """An RGBA (0-1) colour as it looks drawn over the floor (its squares' mean): opaque, for a key
    that shows a translucent mark on a background of its own."""
    floor = [(a + b) / 2 for a, b in zip(*FLOOR_RGB)]
    alpha = rgba[3]
    return tuple(alpha * c + (1 - alpha) * f for c, f in zip(rgba[:3], floor)) + (1.0,)


def hex_colour(rgba: tuple) -> str:
    """'#rrggbb' of an RGBA (0-1) colour; alpha is dropped."""
    return "#" + "".join(f"{round(255 * c):02x}" for c in rgba[:3])


def rgb255(rgba: tuple) -> tuple[int, int, int]:
    """(r, g, b) 0-255 of an RGBA (0-1) colour."""
    return tuple(round(255 * c) for c in rgba[:3])
