"""Restart policy: when a process that exited is started again, and when the launcher gives up.

Pure logic over the times and exit codes the launcher observes, so it is tested with made-up
times. A stage runs until the graph stops it, so any exit while the graph runs is a failure,
exit status 0 included (a stage that returns early is broken, not finished); the launcher
also kills a process that hung (no heartbeat for the graph's ``hang_timeout_s``) and then
treats its exit like any other.

A process may be restarted ``max_restarts`` times within any ``restart_window_s``; each
restart waits ``backoff_s`` doubled for every restart already in the window (at most
``MAX_BACKOFF_S``). Past the limit the process has failed for good; if its
``stop_graph_on_failure`` is set, the whole graph stops.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from agent.runtime.launch import ProcessSpec

MAX_BACKOFF_S = 4.0


@dataclass(frozen=True)
class Decision:
    """What to do about an exit: ``action`` is "restart" or "give-up"."""

    action: str
    delay_s: float = 0.0
    reason: str = ""


@dataclass
class RestartTracker:
    """Restart bookkeeping for one process."""

    spec: ProcessSpec
    restarts: int = 0
    _recent: deque[float] = field(default_factory=deque)

    def on_exit(self, now_s: float, exit_code: int, cause: str = "") -> Decision:
        """What to do about an exit while the graph runs; ``cause`` if the launcher caused it."""
        if cause:
            what = cause
        elif exit_code == 0:
            what = "exited with status 0 while the graph runs"
        else:
            what = f"exit code {exit_code}"
        if self.spec.restart == "never":
            return Decision("give-up", reason=f"{what}; restart = never")
        while self._recent and now_s - self._recent[0] > self.spec.restart_window_s:
            self._recent.popleft()
        if len(self._recent) >= self.spec.max_restarts:
            return Decision(
                "give-up",
                reason=(
                    f"{len(self._recent)} restarts within {self.spec.restart_window_s:g} s "
                    f"(limit {self.spec.max_restarts}); last: {what}"
                ),
            )
        delay = min(MAX_BACKOFF_S, self.spec.backoff_s * 2 ** len(self._recent))
        self._recent.append(now_s)
        self.restarts += 1
        return Decision("restart", delay, f"{what}; restart {self.restarts}")
