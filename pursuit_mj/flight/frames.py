"""Frames of a flight: drone estimate frame -> lab frame -> layout frame, and the fit between them.

All maps are planar (x, y); heights are never scaled. Arrays broadcast over leading
dimensions; the last dimension holds (x, y).

- layout = scale * R(-yaw) (lab - origin): `origin` is the layout's origin (its lower-left
  corner) in lab coordinates (m), `yaw` the angle of the layout's x axis in the lab frame
  (rad, counter-clockwise), `scale` layout metres per lab metre.
- lab = start + R(start_yaw) estimate for drones whose estimate starts at their own take-off
  spot (flow deck); lab = estimate for shared positioning systems (Lighthouse, Loco).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..planar import rotate


@dataclasses.dataclass(frozen=True)
class LabTransform:
    """lab -> layout similarity: origin (m, lab frame), yaw (rad), scale (layout m per lab m)."""

    origin: tuple[float, float] = (0.0, 0.0)
    yaw: float = 0.0
    scale: float = 1.0

    def to_layout(self, p_lab: np.ndarray) -> np.ndarray:
        """Positions (..., 2) m lab -> (..., 2) m layout."""
        return self.scale * rotate(np.asarray(p_lab, np.float64) - np.asarray(self.origin), -self.yaw)

    def to_lab(self, p_layout: np.ndarray) -> np.ndarray:
        """Positions (..., 2) m layout -> (..., 2) m lab."""
        return np.asarray(self.origin) + rotate(np.asarray(p_layout, np.float64), self.yaw) / self.scale

    def velocity_to_layout(self, v_lab: np.ndarray) -> np.ndarray:
        """Velocities (..., 2) m/s lab -> (..., 2) m/s layout."""
        return self.scale * rotate(np.asarray(v_lab, np.float64), -self.yaw)

    def velocity_to_lab(self, v_layout: np.ndarray) -> np.ndarray:
        """Velocities (..., 2) m/s layout -> (..., 2) m/s lab."""
        return rotate(np.asarray(v_layout, np.float64), self.yaw) / self.scale


@dataclasses.dataclass(frozen=True)
class DroneFrames:
    """Per drone: where its estimate frame sits in the lab.

    offset (D, 2) m lab: the estimate frame's origin; yaw (D,) rad: its x axis in the lab.
    Shared positioning systems have offset 0 and yaw 0.
    """

    offset: np.ndarray
    yaw: np.ndarray

    def to_lab(self, p_est: np.ndarray) -> np.ndarray:
        """Estimated positions (D, 2) m -> lab (D, 2) m."""
        return self.offset + rotate(p_est, self.yaw)

    def velocity_to_lab(self, v_est: np.ndarray) -> np.ndarray:
        """Estimated velocities (D, 2) m/s -> lab (D, 2) m/s."""
        return rotate(v_est, self.yaw)

    def velocity_to_drone(self, v_lab: np.ndarray) -> np.ndarray:
        """Lab velocities (D, 2) m/s -> each drone's own world frame (D, 2) m/s (what cflib sends)."""
        return rotate(v_lab, -self.yaw)


@dataclasses.dataclass(frozen=True)
class Fit:
    """A measured transform and how well it explains the spots: residuals (K,) m in the layout frame."""

    transform: LabTransform
    residuals: np.ndarray

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2)))


def fit_similarity(lab: np.ndarray, layout: np.ndarray, source: str = "spots") -> Fit:
    """Least-squares 2D similarity (scale, rotation, translation) with layout ~ scale R (lab - origin).

    lab (K, 2) m: measured positions in the lab frame; layout (K, 2) m: the known spots in
    the layout frame, same order. Needs at least two distinct spots; raises ValueError
    naming `source` otherwise. Closed form after Umeyama (1991), no reflection.
    """
    a = np.asarray(lab, np.float64)
    b = np.asarray(layout, np.float64)
    if a.ndim != 2 or a.shape[-1] != 2 or a.shape != b.shape:
        raise ValueError(f"{source}: expected two lists of [x, y] of the same length, got shapes {a.shape} and {b.shape}")
    if len(a) < 2:
        raise ValueError(f"{source}: need at least 2 spots to measure a transform, got {len(a)}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError(f"{source}: spots must be finite numbers")
    ma, mb = a.mean(0), b.mean(0)
    da, db = a - ma, b - mb
    var_a = float((da**2).sum())
    if var_a < 1e-8 or float((db**2).sum()) < 1e-8:
        raise ValueError(f"{source}: the spots coincide; place the drones at least a few centimetres apart")
    # complex-number form: db ~ s e^{-i yaw} da  =>  s e^{-i yaw} = sum(db * conj(da)) / sum(|da|^2)
    za = da[:, 0] + 1j * da[:, 1]
    zb = db[:, 0] + 1j * db[:, 1]
    k = complex(np.sum(zb * np.conj(za)) / var_a)
    scale = abs(k)
    yaw = -math.atan2(k.imag, k.real)
    # mb = s R(-yaw) (ma - origin)  =>  origin = ma - R(yaw) mb / s
    origin = ma - rotate(mb, yaw) / scale
    t = LabTransform((float(origin[0]), float(origin[1])), float(yaw), float(scale))
    residuals = np.linalg.norm(t.to_layout(a) - b, axis=-1)
    return Fit(t, residuals)
