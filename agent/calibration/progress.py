"""The progress callback that the long-running procedures take."""

from __future__ import annotations

from collections.abc import Callable

Progress = Callable[[int, int], None]  # (done, total) callback for a progress bar
