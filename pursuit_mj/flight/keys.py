"""Keys during a flight: `e` or space cuts every motor at once, `l` lands everyone.

A daemon thread reads single key presses from a file descriptor (the terminal, switched to
cbreak mode so that keys need no Enter, and restored on stop). Ctrl-C and Ctrl-\\ work
independently of it (the bridge's signal handlers).
"""

from __future__ import annotations

import os
import select
import threading
from typing import Callable

ESTOP_KEYS = frozenset("e ")
LAND_KEYS = frozenset("l")


class KeyWatcher:
    """Calls on_estop() / on_land() for the keys above read from `fd` until stopped."""

    def __init__(self, on_estop: Callable[[], None], on_land: Callable[[], None], fd: int | None = None):
        self.on_estop, self.on_land = on_estop, on_land
        self.fd = fd
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._saved = None

    def __enter__(self) -> "KeyWatcher":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> None:
        if self.fd is None:
            return
        if os.isatty(self.fd):
            import termios
            import tty

            self._saved = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)
        self._thread = threading.Thread(target=self._run, name="flight-keys", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)
        if self._saved is not None:
            import termios

            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            self._saved = None

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.fd], [], [], 0.1)
            if not ready:
                continue
            data = os.read(self.fd, 64)
            if not data:
                return
            keys = data.decode("utf-8", "ignore").lower()
            if ESTOP_KEYS & set(keys):
                self.on_estop()
            elif LAND_KEYS & set(keys):
                self.on_land()
