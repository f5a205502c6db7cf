"""Head control with the serial backend: a real head (or its emulator) over a serial line.

The stage speaks ``docs/head-protocol.md`` through :class:`agent.head_link.host.HeadLink`
and a *transport* it is given (the ``head`` process gives it pyserial's port; tests give it
a pipe to an emulated head), so that the stage stays free of ports and clocks.

* ``head_command``: the pan, window and laser the planner wants, sent as they change.
* Every 2 ms: the port's bytes in, the link's out; each completed sweep published as
  ``raw_scan`` (on the graph's clock, through the link's clock alignment), ``head_state``
  with each sweep and every 0.1 s.
* ``head_state.mode`` is ``fault`` (so the environment vector's ``sensor_ok`` is false)
  while the head is not streaming good samples: no port, no handshake, the laser tripped or
  off, or no sample for 0.2 s; ``command_message`` says which.
* The port vanishing (any ``OSError``) closes it; it is reopened after 0.1 s, then 0.2, 0.4,
  … up to 3.2 s between attempts, and the handshake starts again. A head that tripped its
  laser (a lost heartbeat while the port was gone, say) is asked to re-arm once a second
  while the planner wants the laser on; the head re-arms only once the cause is gone.
* No valid frame for 2 s on an open port: one log line naming the port and the likely
  cause, ``command_message`` the same, and a count: ``line_garbled`` when bytes came
  (a wrong baud rate, or no head at the other end), ``head_silent`` when none did (the head
  is off, unplugged or hung). Counted once a spell; logged at the first spell and then at
  most once a minute; a line when valid frames come again.
* Counters (the heartbeat): the link's (frames, CRC, COBS, short, length and oversize
  errors, sequence gaps and restarts, bytes and frames dropped, refusals, protocol errors,
  sweeps, samples; carried across reconnects), the port's (``reconnects``,
  ``open_failures``, ``port_lost``) and the spells above.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Callable
from typing import Protocol

from agent.head_link.frames import FrameDecoder
from agent.head_link.host import HeadLink
from agent.head_link.messages import SafetyState
from agent.runtime import topics
from agent.runtime.messages import HeadCommand, Header, HeadState, Message, stamp_ns
from agent.runtime.stage import Output, Params, Stage
from agent.stages.head_stage import raw_scan_message

__all__ = ["SerialHeadStage", "Transport"]

POLL_S = 0.002
STATE_PERIOD_S = 0.1
BACKOFF_S = (0.1, 3.2)  # first and longest wait between attempts to open the port
REARM_EVERY_S = 1.0
NO_FRAME_S = 2.0  # an open port with no valid frame this long: reported (module docstring)
REPORT_EVERY_S = 60.0  # at most one such log line a minute

log = logging.getLogger(__name__)


class Transport(Protocol):
    """A byte pipe to the head: non-blocking ``read`` (whatever is there, maybe nothing),
    ``write``, ``close``; ``OSError`` when the line is gone."""

    def read(self) -> bytes: ...
    def write(self, data: bytes) -> None: ...
    def close(self) -> None: ...


class SerialHeadStage(Stage):
    """The head process's logic with the serial backend (module docstring).

    Parameters
    ----------
    opener
        Opens the transport (raises ``OSError`` when it cannot).
    port, baud
        What the opener opens, for the reports (``baud`` ``None``: not known).
    """

    def __init__(
        self,
        opener: Callable[[], Transport],
        name: str = "head",
        port: str = "the head's port",
        baud: int | None = None,
    ) -> None:
        self.opener = opener
        self.name = name
        self.port = port
        self.baud = baud
        self.link = HeadLink()
        self.transport: Transport | None = None
        self._next: float | None = None
        self._reopen_at = -math.inf
        self._backoff = BACKOFF_S[0]
        self._next_state = -math.inf
        self._next_rearm = -math.inf
        self._wanted = (0.0, -math.radians(20.0), math.radians(20.0), True)
        self._command_seq = -1
        self.sweeps = 0
        self._port = {
            "reconnects": 0, "open_failures": 0, "port_lost": 0, "line_garbled": 0,
            "head_silent": 0,
        }  # fmt: skip
        self._opened_once = False
        # The last valid frame (or the port's opening): when, and the decoder's byte count.
        self._last_frame = (-math.inf, 0, 0)  # (time, frames, bytes)
        self._quiet_spell = ""  # the spell without a valid frame going on: its counter's name
        self._quiet_since = -math.inf  # ... and the last valid frame (or opening) before it
        self._next_report = -math.inf

    @classmethod
    def from_params(
        cls, params: Params, opener: Callable[[str, int], Transport], name: str = "head"
    ) -> SerialHeadStage:
        """``port`` (a device path) and ``baud`` (921,600) from the launch file; ``opener``
        opens them."""
        port = params.string("port", "")
        if not port:
            raise ValueError(f"{params.process}: the serial backend needs params.port")
        baud = params.integer("baud", 921_600)
        return cls(lambda: opener(port, baud), name=name, port=port, baud=baud)

    # ------------------------------------------------------------------------ the port
    def _open(self, now_s: float) -> None:
        try:
            self.transport = self.opener()
        except OSError:
            self._port["open_failures"] += 1
            self._reopen_at = now_s + self._backoff
            self._backoff = min(2.0 * self._backoff, BACKOFF_S[1])
            return
        if self._opened_once:
            self._port["reconnects"] += 1
        self._opened_once = True
        self._backoff = BACKOFF_S[0]
        # A new link (the head may have restarted); its counts go on across links.
        counts = self.link.decoder.counters
        self.link = HeadLink(
            decoder=FrameDecoder(counters=counts), counters=dict(self.link.counters)
        )
        self.link.command(*self._wanted)
        self._last_frame = (now_s, counts.frames, counts.bytes)

    def _lost(self, now_s: float) -> None:
        self._port["port_lost"] += 1
        if self.transport is not None:
            with contextlib.suppress(OSError):
                self.transport.close()
        self.transport = None
        self._reopen_at = now_s + self._backoff

    # ------------------------------------------------------------------------- stage
    def start(self, now_s: float) -> list[Output]:
        self._next = now_s
        return [(topics.HEAD_STATE, self.state(now_s))]

    def next_tick_s(self) -> float | None:
        return self._next

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic != topics.HEAD_COMMAND or not isinstance(msg, HeadCommand):
            return []
        self._command_seq = msg.header.seq
        self._wanted = (msg.pan_rad, msg.window_low_rad, msg.window_high_rad, msg.laser)
        self.link.command(*self._wanted)
        self.link.last_refusal = None  # a new command: judged afresh
        return [(topics.HEAD_STATE, self.state(now_s))]

    def tick(self, now_s: float) -> list[Output]:
        self._next = now_s + POLL_S
        out: list[Output] = []
        if self.transport is None and now_s >= self._reopen_at:
            self._open(now_s)
        if self.transport is not None:
            try:
                sweeps = self.link.feed(self.transport.read(), now_s)
                status = self.link.status
                if (
                    self.link.connected and status is not None
                    and status.state is SafetyState.TRIPPED and self._wanted[3]
                    and now_s >= self._next_rearm
                ):  # fmt: skip
                    self.link.rearm()
                    self._next_rearm = now_s + REARM_EVERY_S
                self.link.poll(now_s)
                data = self.link.take_output()
                if data:
                    self.transport.write(data)
            except OSError:
                self._lost(now_s)
                sweeps = []
            self._watch_frames(now_s)
            for sweep in sweeps:
                out.append((topics.RAW_SCAN, raw_scan_message(sweep, self.sweeps)))
                self.sweeps += 1
            if sweeps:
                out.append((topics.HEAD_STATE, self.state(now_s)))
                self._next_state = now_s + STATE_PERIOD_S
        if now_s >= self._next_state:
            out.append((topics.HEAD_STATE, self.state(now_s)))
            self._next_state = now_s + STATE_PERIOD_S
        return out

    # ------------------------------------------------------------------- no valid frame
    def _watch_frames(self, now_s: float) -> None:
        """Note each valid frame; report a spell of :data:`NO_FRAME_S` without one."""
        counts = self.link.decoder.counters
        if counts.frames != self._last_frame[1]:
            if self._quiet_spell:
                log.info(
                    "valid frames from %s again, after %.1f s without",
                    self.port,
                    now_s - self._quiet_since,
                )
            self._last_frame = (now_s, counts.frames, counts.bytes)
            self._quiet_spell = ""
            return
        if self.transport is None or now_s - self._last_frame[0] < NO_FRAME_S:
            return
        if self._quiet_spell:
            return
        got_bytes = counts.bytes > self._last_frame[2]
        self._quiet_spell = "line_garbled" if got_bytes else "head_silent"
        self._quiet_since = self._last_frame[0]
        self._port[self._quiet_spell] += 1
        if now_s >= self._next_report:
            spells = self._port["line_garbled"] + self._port["head_silent"]
            log.warning("%s (spell %d without valid frames)", self._no_frame(now_s), spells)
            self._next_report = now_s + REPORT_EVERY_S

    def _no_frame(self, now_s: float) -> str:
        """Why no valid frame came for :data:`NO_FRAME_S` on the open port, or ``""``."""
        when, _, bytes_then = self._last_frame
        if self.transport is None or now_s - when < NO_FRAME_S:
            return ""
        got = self.link.decoder.counters.bytes - bytes_then
        rate = f" at {self.baud} baud" if self.baud is not None else ""
        if got:
            return (
                f"no valid frame from {self.port} in {now_s - when:.1f} s{rate} ({got} bytes "
                "received): wrong baud rate, or not a head"
            )
        return (
            f"nothing from {self.port} in {now_s - when:.1f} s: the head is not answering "
            "(off, disconnected or hung)"
        )

    # ------------------------------------------------------------------------ state
    def _why_not_streaming(self, now_s: float) -> str:
        link = self.link
        if self.transport is None:
            return "serial port not open"
        no_frame = self._no_frame(now_s)
        if no_frame:
            return no_frame
        if not link.connected:
            return "no handshake with the head"
        status = link.status
        if status is None:
            return "no status from the head"
        if status.state is SafetyState.TRIPPED:
            return "head laser tripped"
        if not status.laser_on:
            return "head laser off"
        if not link.streaming(now_s):
            return "no samples from the head"
        return ""

    def state(self, now_s: float) -> HeadState:
        status = self.link.status
        why = self._why_not_streaming(now_s)
        pan, low, high, laser = self._wanted
        refused = self.link.last_refusal
        return HeadState(
            header=Header(stamp_ns=stamp_ns(now_s), frame_id="base_link"),
            pan_rad=status.pan_rad if status is not None else 0.0,
            pan_rate_rad_s=self.link.pan_rate_rad_s, target_pan_rad=pan,
            window_low_rad=status.window_low_rad if status is not None else low,
            window_high_rad=status.window_high_rad if status is not None else high,
            laser_on=not why, mode="fault" if why and laser else ("scanning" if laser else "idle"),
            command_seq=self._command_seq, command_accepted=refused is None,
            command_message=why or ("" if refused is None else refused.text),
            sweeps=self.sweeps,
        )  # fmt: skip

    def counters(self) -> dict[str, int]:
        frames = self.link.decoder.counters
        return {
            **self.link.counters, **self._port, "frames": frames.frames,
            "crc_errors": frames.crc_errors, "cobs_errors": frames.cobs_errors,
            "short_frames": frames.short, "length_errors": frames.length_errors,
            "oversize_runs": frames.oversize, "bytes_dropped": frames.discarded_bytes,
            "frames_dropped": frames.dropped, "seq_gaps": frames.seq_gaps,
            "seq_backwards": frames.seq_backwards,
        }  # fmt: skip
