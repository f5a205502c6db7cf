"""Head control with the simulated backend: pan, scan window, laser safety, raw scans.

The head pans the whole sensor within ±90° under rate and acceleration limits and sweeps the
mirror back and forth over the commanded window (40° per 100 ms, so a narrower window gives
more sweeps per second). It may scan while it slews; every sample carries the pan of its
moment. A command outside the head's limits is refused: the laser goes off, the mirror parks,
and the head state says why, until a command it can honour arrives. With ``watchdog_s`` set,
the laser also goes off when no command has come for that long.

Inputs: ``head_command``, ``world_truth`` (the true vehicle motion the simulated sensor
moves with). Outputs: ``raw_scan`` at the end of every sweep, ``head_state`` with every sweep
and after every command.

The world's movers are placed by the simulator at each fine step's own time: a sweep starts
at the graph clock's ``start`` (``start_time_s``) and every step's time is ``start`` plus its
offset, the same clock the world stage publishes the movers' truth on
(:mod:`agent.sim.movers`), so the head and the world agree on where a mover is without a
message between them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from agent.arrays import FloatArray
from agent.errors import HeadCommandError
from agent.kinematics.trajectory import ConstantTwist, StaticPose, Trajectory
from agent.runtime import topics
from agent.runtime.messages import (
    HeadCommand,
    Header,
    HeadState,
    Message,
    RawScan,
    WorldTruth,
    stamp_ns as to_ns,
)
from agent.runtime.stage import Output, Params, Stage
from agent.sensor.params import SensorParameters, simulated_head
from agent.sensor.samples import RawSamples
from agent.sensor.scanning import ScanWindow, sweep_timing, validate_pan
from agent.sim.simulator import SensorSimulator
from agent.sim.world import World
from agent.sim.world_file import load_world

IDLE_STATE_PERIOD_S = 0.1  # head_state rate while the laser is off
_PAN_STEP_S = 1e-3  # integration step of the pan axis
_PAN_TOLERANCE_RAD = 1e-4


@dataclass
class PanAxis:
    """The pan axis: position and rate, moving to a target under rate and acceleration limits.

    Motion is the time-optimal profile, evaluated exactly: brake first if moving away from the
    target or too fast to stop on it, then accelerate, coast at the rate limit if it is
    reached, and brake to stop on the target. A new target re-plans from the current state.
    """

    max_rate_rad_s: float
    max_accel_rad_s2: float
    position_rad: float = 0.0
    rate_rad_s: float = 0.0
    target_rad: float = 0.0

    @property
    def settled(self) -> bool:
        return (
            abs(self.target_rad - self.position_rad) < _PAN_TOLERANCE_RAD
            and abs(self.rate_rad_s) < 1e-9
        )

    def _phases(self) -> list[tuple[float, float]]:
        """The plan from the current state: (duration, acceleration) pieces."""
        a, vmax = self.max_accel_rad_s2, self.max_rate_rad_s
        p, v, target = self.position_rad, self.rate_rad_s, self.target_rad
        phases: list[tuple[float, float]] = []
        error = target - p
        stop = v * abs(v) / (2 * a)  # where braking now would stop, relative to p
        if v != 0.0 and (v * error < 0 or abs(stop) > abs(error) + 1e-12):
            phases.append((abs(v) / a, -math.copysign(a, v)))  # brake to rest first
            p, v = p + stop, 0.0
            error = target - p
        if error == 0.0:
            return phases
        s = math.copysign(1.0, error)
        u = abs(v)  # speed towards the target, from which it can still stop in time
        peak = min(vmax, math.sqrt(a * abs(error) + 0.5 * u * u))
        d_up = (peak * peak - u * u) / (2 * a)
        d_down = peak * peak / (2 * a)
        phases.append(((peak - u) / a, s * a))
        phases.append((max(0.0, abs(error) - d_up - d_down) / peak, 0.0))
        phases.append((peak / a, -s * a))
        return phases

    def advance(self, duration_s: float) -> tuple[FloatArray, FloatArray]:
        """Move for ``duration_s``; return times (from 0, 1 ms apart) and positions then."""
        n = max(1, math.ceil(max(duration_s, 0.0) / _PAN_STEP_S))
        times = np.linspace(0.0, max(duration_s, 0.0), n + 1)
        if self.settled:
            self.position_rad, self.rate_rad_s = self.target_rad, 0.0
            return times, np.full(n + 1, self.position_rad)
        positions = np.full(n + 1, self.target_rad)
        p, v, t0 = self.position_rad, self.rate_rad_s, 0.0
        for span, acc in self._phases():  # at most four pieces
            inside = (times >= t0) & (times < t0 + span)
            tau = times[inside] - t0
            positions[inside] = p + v * tau + 0.5 * acc * tau * tau
            if duration_s < t0 + span:  # the move goes on after this call
                tau_end = duration_s - t0
                self.position_rad = p + v * tau_end + 0.5 * acc * tau_end * tau_end
                self.rate_rad_s = v + acc * tau_end
                return times, positions
            p, v, t0 = p + v * span + 0.5 * acc * span * span, v + acc * span, t0 + span
        self.position_rad, self.rate_rad_s = self.target_rad, 0.0
        return times, positions


def raw_scan_message(raw: RawSamples, sweep_index: int) -> RawScan:
    """A sweep's samples as the head publishes them: stamped with the last sample's time, in
    the ``head`` frame."""
    return RawScan(
        header=Header(stamp_ns=to_ns(float(raw.time_s[-1])), frame_id="head"),
        time_s=raw.time_s, mirror_angle_rad=raw.mirror_angle_rad, pan_rad=raw.pan_rad,
        current_1_A=raw.current_1_A, current_2_A=raw.current_2_A,
        direction=raw.direction, sweep_index=sweep_index,
    )  # fmt: skip


class HeadStage(Stage):
    """The head process's logic with the simulated sensor as its backend."""

    def __init__(
        self,
        world: World,
        seed: int = 0,
        params: SensorParameters | None = None,
        watchdog_s: float = 0.0,
        name: str = "head",
    ) -> None:
        self.params = params if params is not None else simulated_head()
        self.world = world
        self.seed = seed
        self.name = name
        self.watchdog_s = watchdog_s
        self.simulator = SensorSimulator(
            world, self.params, np.random.default_rng(seed), continuous=True
        )
        self.pan = PanAxis(
            self.params.pan_rate_limit_rad_s, self.params.pan_acceleration_limit_rad_s2
        )
        self.window = ScanWindow.full(self.params)
        self.laser_on = True
        self.fault = ""
        self.direction = 1
        self.sweeps = 0
        self._sweep_start: float | None = None
        self._next: float | None = None
        self._truth: WorldTruth | None = None
        self._last_command_s: float | None = None
        self._command_seq = -1
        self._accepted = True
        self._message = ""
        self._pending_window: ScanWindow | None = None
        # The pan axis is integrated up to _pan_clock; _track holds (time, pan) since the
        # current sweep began, so every sample gets the pan of its own moment.
        self._pan_clock: float | None = None
        self._track: list[tuple[float, float]] = []
        self._counts = {"commands": 0, "refused": 0, "late_sweeps": 0, "watchdog_trips": 0}

    @classmethod
    def from_params(cls, params: Params, name: str = "head") -> HeadStage:
        stage = cls(
            load_world(params.string("world", "")),
            seed=params.integer("seed", 0),
            watchdog_s=params.number("watchdog_s", 0.0, lo=0.0),
            name=name,
        )
        params.check_all_read()
        return stage

    # ------------------------------------------------------------------------------ timing
    def _duration(self) -> float:
        timing = sweep_timing(self.window, self.direction, 0.0, self.params)
        return timing.duration_s

    def _move_pan(self, until_s: float) -> None:
        """Integrate the pan axis up to ``until_s``, recording its track."""
        if self._pan_clock is None:
            self._pan_clock = until_s
            self._track = [(until_s, self.pan.position_rad)]
            return
        dt = until_s - self._pan_clock
        if dt > 0:
            times, positions = self.pan.advance(dt)
            self._track += zip(
                (times[1:] + self._pan_clock).tolist(), positions[1:].tolist(), strict=True
            )
            self._pan_clock = until_s

    def _restart_track(self) -> None:
        if self._pan_clock is not None:
            self._track = [(self._pan_clock, self.pan.position_rad)]

    def start(self, now_s: float) -> list[Output]:
        self._move_pan(now_s)
        self._sweep_start = now_s
        self._last_command_s = now_s
        self._next = now_s + (self._duration() if self.laser_on else IDLE_STATE_PERIOD_S)
        return [(topics.HEAD_STATE, self.state(now_s))]

    def next_tick_s(self) -> float | None:
        return self._next

    # ----------------------------------------------------------------------------- inputs
    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic == topics.WORLD_TRUTH and isinstance(msg, WorldTruth):
            self._truth = msg
            return []
        if topic != topics.HEAD_COMMAND or not isinstance(msg, HeadCommand):
            return []
        self._counts["commands"] += 1
        self._command_seq = msg.header.seq
        self._last_command_s = now_s
        try:
            target = validate_pan(msg.pan_rad, self.params)
            window = ScanWindow(msg.window_low_rad, msg.window_high_rad).validate(self.params)
        except HeadCommandError as exc:
            self._refuse(str(exc), now_s)
        else:
            self._move_pan(now_s)  # up to now the axis moved towards the old target
            self.pan.target_rad = target
            self._accepted, self._message, self.fault = True, "", ""
            if not msg.laser:
                self._laser_off(now_s, "laser off by command")
            elif not self.laser_on:
                self._resume(now_s, window)
            else:
                self._pending_window = window  # takes effect at the next sweep
        return [(topics.HEAD_STATE, self.state(now_s))]

    def _refuse(self, why: str, now_s: float) -> None:
        self._counts["refused"] += 1
        self._laser_off(now_s, f"refused: {why}; laser off until a valid command")
        self._accepted = False

    def _laser_off(self, now_s: float, why: str) -> None:
        self.laser_on = False
        self._message = why
        self._pending_window = None
        self._next = now_s + IDLE_STATE_PERIOD_S

    def _resume(self, now_s: float, window: ScanWindow) -> None:
        self.laser_on = True
        self.window = window
        self._pending_window = None
        self._sweep_start = now_s
        self._next = now_s + self._duration()

    # ------------------------------------------------------------------------------ ticks
    def tick(self, now_s: float) -> list[Output]:
        if (
            self.watchdog_s > 0
            and self.laser_on
            and self._last_command_s is not None
            and now_s - self._last_command_s > self.watchdog_s
        ):
            self._counts["watchdog_trips"] += 1
            self.fault = "watchdog"
            self._laser_off(now_s, f"no head command for {self.watchdog_s:g} s: laser off")
        if not self.laser_on:
            self._move_pan(now_s)
            self._restart_track()
            self._next = now_s + IDLE_STATE_PERIOD_S
            return [(topics.HEAD_STATE, self.state(now_s))]
        return self._sweep(now_s)

    def _trajectory(self) -> Trajectory:
        t = self._truth
        if t is None:
            x, y, yaw = self.world.vehicle_pose
            return StaticPose(x, y, yaw)
        return ConstantTwist(
            t.x_m, t.y_m, t.yaw_rad, t.speed_m_s, t.yaw_rate_rad_s, t.header.stamp_s
        )

    def _sweep(self, now_s: float) -> list[Output]:
        start = self._sweep_start if self._sweep_start is not None else now_s
        duration = self._duration()
        if now_s - (start + duration) > duration:  # the process was stalled: resynchronise
            self._counts["late_sweeps"] += 1
            start = now_s - duration
        self._move_pan(start + duration)
        track_t, track_p = (np.array(v) for v in zip(*self._track, strict=True))

        def pan_at(t: FloatArray) -> FloatArray:
            return np.asarray(np.interp(np.asarray(t), track_t, track_p), dtype=np.float64)

        # Each sweep's noise depends only on (seed, sweep number): the same scans whatever
        # the timing, in lock-step or in real time.
        self.simulator.rng = np.random.default_rng([self.seed, self.sweeps])
        raw, _ = self.simulator.sweep(
            self.window,
            direction=self.direction,
            pan_rad=pan_at,
            start_time_s=start,
            trajectory=self._trajectory(),
            with_truth=False,
        )
        end = start + duration
        message = raw_scan_message(raw, self.sweeps)
        self.sweeps += 1
        self.direction = -self.direction
        if self._pending_window is not None:
            self.window, self._pending_window = self._pending_window, None
        self._sweep_start = end
        self._restart_track()
        self._next = end + self._duration()
        return [(topics.RAW_SCAN, message), (topics.HEAD_STATE, self.state(end))]

    # ------------------------------------------------------------------------------ state
    def state(self, now_s: float) -> HeadState:
        if not self.laser_on:
            mode = "fault" if self.fault else "idle"
        else:
            mode = "scanning" if self.pan.settled else "slewing"
        return HeadState(
            header=Header(stamp_ns=to_ns(now_s), frame_id="base_link"),
            pan_rad=self.pan.position_rad, pan_rate_rad_s=self.pan.rate_rad_s,
            target_pan_rad=self.pan.target_rad, window_low_rad=self.window.low_rad,
            window_high_rad=self.window.high_rad, laser_on=self.laser_on, mode=mode,
            command_seq=self._command_seq, command_accepted=self._accepted,
            command_message=self._message, sweeps=self.sweeps,
        )  # fmt: skip

    def counters(self) -> dict[str, int]:
        return dict(self._counts, sweeps=self.sweeps)
