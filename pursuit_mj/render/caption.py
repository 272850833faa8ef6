"""A caption band composited onto a frame with Pillow: title, step, time and outcome."""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

OUTCOME_RGB = {
    "": (235, 235, 235),
    "success": (90, 220, 110),
    "collision": (255, 90, 80),
    "timeout": (255, 190, 60),
}


@dataclasses.dataclass(frozen=True)
class Caption:
    """What the band says: `title` (left, first line), step/max_steps, sim time (s) and outcome ('' while running)."""

    title: str
    step: int
    max_steps: int
    time: float
    outcome: str = ""

    def status(self) -> str:
        return f"step {self.step}/{self.max_steps}   t = {self.time:.1f} s"

    def outcome_text(self) -> str:
        return self.outcome.upper() if self.outcome else "running"


@lru_cache(maxsize=8)
def _font(size: int) -> ImageFont.ImageFont:
    return ImageFont.load_default(size=size)


def _metrics(height: int) -> tuple[int, int, int]:
    """(font size, padding, band height) in pixels for a frame `height` pixels tall."""
    size = max(9, height // 32)
    pad = max(3, size // 3)
    return size, pad, 2 * size + 3 * pad


def band_height(height: int) -> int:
    """Pixels the caption band covers at the top of a frame `height` pixels tall."""
    return _metrics(height)[2]


def draw_caption(frame: np.ndarray, caption: Caption) -> np.ndarray:
    """A copy of frame (H, W, 3) uint8 with a translucent band across the top holding the caption."""
    h, w = frame.shape[:2]
    size, pad, band = _metrics(h)
    img = Image.fromarray(frame)
    overlay = Image.new("RGBA", (w, band), (15, 18, 24, 170))
    img.paste(overlay, (0, 0), overlay)
    d = ImageDraw.Draw(img)
    font = _font(size)
    d.text((pad, pad), caption.title, font=font, fill=(245, 245, 245))
    d.text((pad, 2 * pad + size), caption.status(), font=font, fill=(220, 220, 220))
    text = caption.outcome_text()
    big = _font(int(size * 1.3))
    tw = d.textlength(text, font=big)
    d.text((w - pad - tw, (band - int(size * 1.3)) // 2), text, font=big, fill=OUTCOME_RGB.get(caption.outcome, OUTCOME_RGB[""]))
    return np.asarray(img)
