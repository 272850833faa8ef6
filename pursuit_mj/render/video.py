"""Writing frames: mp4 (h264) or gif through mediapy's streaming writer, and PNG stills.

Every file is written under a temporary name beside its final one and renamed when complete,
so an interrupted render never leaves a half-written file under the final name.
"""

from __future__ import annotations

import math

import contextlib
import os
import re
import shutil
from pathlib import Path
from typing import Iterator

import mediapy
import numpy as np
from PIL import Image

from ..io_utils import CannotWrite, atomic_path

VIDEO_CODECS = {"mp4": "h264", "gif": "gif"}
#: h264 settings: mediapy's quality (qp 20) with a faster preset, since the encoder shares
#: the CPU with the software renderer
H264_ARGS = {"qp": 20, "ffmpeg_args": ["-preset", "veryfast"]}


def video_format(path: str | Path, source: str = "--save-path") -> str:
    """'mp4' or 'gif' from a file name; ValueError naming `source` for any other extension."""
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix not in VIDEO_CODECS:
        raise ValueError(f"{source} {path}: unknown video extension {Path(path).suffix or '(none)'!r} (use .mp4 or .gif)")
    return suffix


def ensure_ffmpeg() -> str:
    """The ffmpeg binary mediapy will use (PATH, else the one imageio-ffmpeg names).

    ValueError in one line when there is none, or when the one imageio-ffmpeg names (its
    IMAGEIO_FFMPEG_EXE, which it returns untested) is not an executable file."""
    exe = shutil.which("ffmpeg")
    if exe is None:
        try:
            import imageio_ffmpeg

            exe = imageio_ffmpeg.get_ffmpeg_exe()
        except (ImportError, RuntimeError) as exc:
            raise ValueError(f"video writing needs ffmpeg: install it (apt install ffmpeg) or the imageio-ffmpeg package ({exc})") from None
        _check_program(exe)
    mediapy.set_ffmpeg(exe)
    return exe


def _check_program(exe: str) -> None:
    """ValueError naming `exe` (and IMAGEIO_FFMPEG_EXE when it came from there) unless it is an executable file."""
    named = os.environ.get("IMAGEIO_FFMPEG_EXE")
    where = f"IMAGEIO_FFMPEG_EXE={exe}" if named and named == exe else f"imageio-ffmpeg's ffmpeg {exe}"
    if not os.path.exists(exe):
        why = "no such program"
    elif not (os.path.isfile(exe) and os.access(exe, os.X_OK)):
        why = "not an executable program"
    else:
        return
    raise ValueError(f"video writing needs ffmpeg: {where}: {why} (install ffmpeg, apt install ffmpeg, or set "
                     f"IMAGEIO_FFMPEG_EXE to one, or unset it)")


def check_frame_size(fmt: str, width: int, height: int) -> None:
    """h264 (yuv420p) needs even sizes: refuse odd ones before rendering anything."""
    if fmt == "mp4" and (width % 2 or height % 2):
        raise ValueError(f"--width {width} / --height {height}: mp4 (h264) needs even frame sizes")


GIF_MAX_FPS = 50.0  # GIF delays are whole hundredths of a second, and players slow any under 0.02 s
#: frame rates (1/s) ffmpeg writes as asked: below, an mp4 drops frames (1e-4) or fails at the end
#: (1e-6) and a GIF's delay overflows; above, an mp4 plays at another rate (1e7) or ffmpeg refuses it
FPS_RANGE = (0.01, 1e6)


def check_video_fps(fmt: str, fps: float, source: str = "fps") -> None:
    """Refuse a frame rate the format cannot play (ValueError naming `source`), before rendering anything."""
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"{source}: expected a positive frame rate, got {fps}")
    lo, hi = FPS_RANGE
    if not lo <= fps <= hi:
        raise ValueError(f"{source}: {fps:g} frames per second is outside what ffmpeg writes correctly ({lo:g}..{hi:g})")
    if fmt == "gif" and fps > GIF_MAX_FPS:
        raise ValueError(f"{source}: {fps:g} frames per second is beyond what a GIF plays (at most {GIF_MAX_FPS:g}; "
                         f"its frame delays are whole hundredths of a second); lower --fps or write mp4")


class VideoFile:
    """Append frames (H, W, 3) uint8 to `path` (.mp4 or .gif); `close(ok)` renames or discards it."""

    def __init__(self, path: str | Path, width: int, height: int, fps: float):
        self.path = Path(path)
        fmt = video_format(self.path)
        check_frame_size(fmt, width, height)
        check_video_fps(fmt, fps)
        ensure_ffmpeg()
        self.frames = 0
        self._finished = False  # the encoder has written the file out (finish)
        self._atomic = atomic_path(self.path)
        tmp = self._atomic.__enter__()
        extra = H264_ARGS if fmt == "mp4" else {}
        self._writer = mediapy.VideoWriter(tmp, (height, width), fps=fps, codec=VIDEO_CODECS[fmt], **extra)
        try:
            self._writer.__enter__()
        except BaseException as exc:
            self._atomic.__exit__(type(exc), exc, exc.__traceback__)
            raise

    def add(self, frame: np.ndarray) -> None:
        """Append one frame (H, W, 3) uint8 RGB of the size the file was opened with.

        CannotWrite naming the file (and nothing left on disk) if the encoder has stopped."""
        try:
            self._writer.add_image(frame)
        except (OSError, RuntimeError) as exc:  # a broken pipe: ffmpeg ended early (a full disk, killed)
            raise self._encoder_stopped(exc) from None
        self.frames += 1

    def finish(self) -> None:
        """Let the encoder write the last frames out: the file is complete under its temporary
        name, for `close` to rename (CannotWrite if the encoder fails; nothing is left then, nor
        on Ctrl-C or SIGTERM meanwhile)."""
        if self._writer is None or self._finished:
            return
        try:
            self._writer.__exit__(None, None, None)
        except (OSError, RuntimeError) as exc:
            raise self._encoder_stopped(exc) from None
        except BaseException:  # Ctrl-C or SIGTERM while ffmpeg writes the last frames out: no part left
            self._discard()
            raise
        self._finished = True

    def close(self, ok: bool = True) -> Path | None:
        """ok: finish the file (if `finish` has not) and rename it onto `path` (CannotWrite if the
        encoder fails or the name cannot be replaced); else discard it."""
        if self._writer is None:
            return None
        if ok:
            self.finish()
            self._writer = None
            try:
                self._atomic.__exit__(None, None, None)  # the rename onto path; the part is gone if it fails
            except OSError as exc:  # path cannot be replaced: another user's file in a sticky-bit folder, a full disk
                raise CannotWrite(f"{self.path}: cannot write it ({exc.strerror or exc})") from None
            return self.path
        self._discard()
        return None

    def _discard(self) -> str:
        """Stop the encoder and remove the temporary file; returns what ffmpeg said if it failed."""
        writer, self._writer = self._writer, None
        err, said = RuntimeError("video abandoned"), ""
        try:
            if not self._finished:  # a finished encoder has ended already
                writer.__exit__(RuntimeError, err, None)
        except Exception as exc:
            said = str(exc)
        with contextlib.suppress(RuntimeError):
            self._atomic.__exit__(RuntimeError, err, None)
        return said

    def _encoder_stopped(self, exc: BaseException) -> CannotWrite:
        """Discard the file; the error to raise, with ffmpeg's last message line."""
        said = self._discard()
        text = re.sub(r"Error writing '[^']*':", "", f"{exc}\n{said}")  # mediapy's wrapper names the temporary file
        lines = [line.strip() for line in text.splitlines() if line.strip()]
        return CannotWrite(f"{self.path}: cannot write it (the ffmpeg encoder stopped: {lines[-1] if lines else 'it exited without a message'})")


@contextlib.contextmanager
def video_file(path: str | Path, width: int, height: int, fps: float) -> Iterator[VideoFile]:
    """A VideoFile that is completed on success and discarded on any exception (Ctrl-C included)."""
    v = VideoFile(path, width, height, fps)
    try:
        yield v
    except BaseException:
        v.close(ok=False)
        raise
    v.close(ok=True)


def save_png(path: str | Path, frame: np.ndarray) -> Path:
    """Write frame (H, W, 3) uint8 as a PNG, atomically; CannotWrite naming it if it cannot be (a full disk)."""
    try:
        with atomic_path(path) as tmp:
            Image.fromarray(np.ascontiguousarray(frame)).save(tmp, format="PNG")
    except OSError as exc:
        raise CannotWrite(f"{path}: cannot write it ({exc.strerror or exc})") from None
    return Path(path)
