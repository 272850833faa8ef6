"""Text composited onto a frame with Pillow: a caption band at the top (title, step, time,
outcome) and a colour key at the bottom (what each mark and colour in the scene means)."""

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


MIN_FONT = 8  # px: the smallest text the caption and the key shrink to


def _fit(d: ImageDraw.ImageDraw, text: str, size: int, room: float) -> tuple[ImageFont.ImageFont, str]:
    """(font, text) for one line at most `room` pixels wide: the font shrunk from `size` down to
    MIN_FONT, then the text cut short with an ellipsis."""
    for fsize in range(size, MIN_FONT - 1, -1):
        font = _font(fsize)
        if d.textlength(text, font=font) <= room:
            return font, text
    while text and d.textlength(text + "…", font=font) > room:
        text = text[:-1]
    return font, (text + "…" if text else "")


def draw_caption(frame: np.ndarray, caption: Caption) -> np.ndarray:
    """A copy of frame (H, W, 3) uint8 with a translucent band across the top holding the caption.

    The two lines on the left are fitted (`_fit`) to the room left of the widest outcome word,
    so that no outcome runs over them and the title keeps one size from the first frame to the last."""
    h, w = frame.shape[:2]
    size, pad, band = _metrics(h)
    img = Image.fromarray(frame)
    overlay = Image.new("RGBA", (w, band), (15, 18, 24, 170))
    img.paste(overlay, (0, 0), overlay)
    d = ImageDraw.Draw(img)
    text = caption.outcome_text()
    big = _font(int(size * 1.3))
    tw = d.textlength(text, font=big)
    widest = max(d.textlength(Caption("", 0, 0, 0.0, o).outcome_text(), font=big) for o in OUTCOME_RGB)
    room = w - 3 * pad - widest
    for line, y, fill in ((caption.title, pad, (245, 245, 245)), (caption.status(), 2 * pad + size, (220, 220, 220))):
        font, line = _fit(d, line, size, room)
        d.text((pad, y), line, font=font, fill=fill)
    d.text((w - pad - tw, (band - int(size * 1.3)) // 2), text, font=big, fill=OUTCOME_RGB.get(caption.outcome, OUTCOME_RGB[""]))
    return np.asarray(img)


KEY_MARKS = ("dot", "ring", "line", "dash", "square")


@dataclasses.dataclass(frozen=True)
class KeyEntry:
    """One item of the colour key: a mark (one of KEY_MARKS) drawn in rgb (0-255), then label."""

    label: str
    rgb: tuple[int, int, int]
    mark: str


def key_band_height(height: int) -> int:
    """Pixels the colour key covers at the bottom of a frame `height` pixels tall."""
    size, pad, _ = _metrics(height)
    return size + 2 * pad


def _draw_mark(d: ImageDraw.ImageDraw, mark: str, x: int, y: int, size: int, rgb: tuple) -> None:
    """The mark in a size x size box whose top-left corner is (x, y)."""
    r = size // 2
    cx, cy = x + r, y + r
    if mark == "dot":
        d.ellipse((cx - r * 0.7, cy - r * 0.7, cx + r * 0.7, cy + r * 0.7), fill=rgb)
    elif mark == "ring":
        d.ellipse((cx - r * 0.8, cy - r * 0.8, cx + r * 0.8, cy + r * 0.8), outline=rgb, width=max(1, size // 8))
    elif mark == "square":
        d.rectangle((x + 1, y + 1, x + size - 2, y + size - 2), fill=rgb)
    elif mark == "line":
        d.line((x, cy, x + size, cy), fill=rgb, width=max(2, size // 6))
    elif mark == "dash":
        for k in range(0, 4, 2):
            d.line((x + k * size // 4, cy, x + (k + 1) * size // 4, cy), fill=rgb, width=max(2, size // 6))
    else:
        raise ValueError(f"key mark {mark!r}: choose from {', '.join(KEY_MARKS)}")


def draw_key(frame: np.ndarray, entries: list[KeyEntry]) -> np.ndarray:
    """A copy of frame (H, W, 3) uint8 with a translucent band across the bottom holding the key.

    Entries are laid out left to right in the caption's font size, smaller where they would
    not fit the width (down to 8 px); what still does not fit is left off the end.
    """
    h, w = frame.shape[:2]
    size, pad, _ = _metrics(h)
    band = key_band_height(h)
    img = Image.fromarray(frame)
    overlay = Image.new("RGBA", (w, band), (15, 18, 24, 170))
    img.paste(overlay, (0, h - band), overlay)
    d = ImageDraw.Draw(img)
    for fsize in range(size, MIN_FONT - 1, -1):
        font = _font(fsize)
        widths = [fsize + fsize // 3 + d.textlength(e.label, font=font) for e in entries]
        if sum(widths) + fsize * (len(entries) - 1) + 2 * pad <= w:
            break
    x, y = pad, h - band + (band - fsize) // 2
    for e, width in zip(entries, widths):
        if x + width > w - pad:
            break
        _draw_mark(d, e.mark, x, y, fsize, e.rgb)
        d.text((x + fsize + fsize // 3, y), e.label, font=font, fill=(235, 235, 235))
        x += int(width) + fsize
    return np.asarray(img)
