"""Restart policy: when a process that exited is started again, and when the launcher gives up.

Pure logic over the times and exit codes the launcher observes, so it is tested with made-up
times. A process may be restarted ``max_restarts`` times within any ``restart_window_s``;
each restart waits ``backoff_s`` doubled for every restart already in the window (at most
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
    """What to do about an exit: ``action`` is "restart", "done" or "give-up"."""

    action: str
    delay_s: float = 0.0
    reason: str = ""


@dataclass
class RestartTracker:
    """Restart bookkeeping for one process."""

    spec: ProcessSpec
    restarts: int = 0
    _recent: deque[float] = field(default_factory=deque)

    def on_exit(self, now_s: float, exit_code: int) -> Decision:
        policy = self.spec.restart
        if policy == "never" or (policy == "on-failure" and exit_code == 0):
            why = "exited cleanly" if exit_code == 0 else f"exited with {exit_code}, restart=never"
            return Decision("done" if exit_code == 0 else "give-up", reason=why)
        while self._recent and now_s - self._recent[0] > self.spec.restart_window_s:
            self._recent.popleft()
        if len(self._recent) >= self.spec.max_restarts:
            return Decision(
                "give-up",
                reason=(
                    f"{len(self._recent)} restarts within {self.spec.restart_window_s:g} s "
                    f"(limit {self.spec.max_restarts}); last exit code {exit_code}"
                ),
            )
        delay = min(MAX_BACKOFF_S, self.spec.backoff_s * 2 ** len(self._recent))
        self._recent.append(now_s)
        self.restarts += 1
        return Decision("restart", delay, f"exit code {exit_code}; restart {self.restarts}")
