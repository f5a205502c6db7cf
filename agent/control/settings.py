"""Every constant of the vehicle controller, with its reason.

Frames follow REP-103; metres, seconds, radians (degrees only in names ending ``_deg``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

__all__ = ["ControllerSettings"]


_MAY_BE_ZERO = frozenset({"drift_ratio_rad_per_m", "drift_track_per_rad", "drift_slip_rad2_per_m"})


@dataclass(frozen=True)
class ControllerSettings:
    """The controller's constants (:mod:`agent.control.controller` says how they are used).

    Timing
    ------
    period_s
        The time between two calls of ``command``: the vehicle stage's 20 Hz. A longer
        interval seen between calls is used instead (the envelope never assumes a faster
        loop than it gets).
    latency_s
        From ``command`` to the base acting on it: one step of the 50 Hz odometry and
        wheel loop, which also covers the transport between processes (a few ms).

    Stopping within known clear space (:mod:`agent.control.clearance`)
    ------------------------------------------------------------------
    cell_m, memory_size_m
        The free-space memory's cells (the agent's own 5 cm grid) and its square about the
        vehicle: the sensor's far limit (2.5 m) plus the mount offset and re-centring slack
        on every side.
    sweep_step_m, sweep_reach_m, outline_spacing_m
        A motion is checked by moving the outline's perimeter points (``outline_spacing_m``
        apart) in steps that move no point by more than ``sweep_step_m`` (one cell, so no
        blocked cell is stepped over), as far as ``sweep_reach_m`` (the braking envelope at
        full speed is 0.33 m; the rest is look-ahead for the planners' scores).
    stop_margin_m
        Kept between the braking envelope's end and the first space not known clear: the
        cells' own size (5 cm) halved, as perimeter points and cells are both discrete.
    window_half_rad
        Within this of the heading, seen from the centre of scanning, the forward window
        (±20°) is certainly scanned while the head looks ahead: there the newest profile
        vouches for space (and silence, below), besides what is remembered. 19.5° is the
        edge of the last 1° sector wholly inside the window (the agent's ±20° sectors reach
        half a degree outside it).
    clear_memory_s
        Space a profile showed clear, or found silent, stays known clear for this many
        seconds of the vehicle's moving (when it was not seen as a possible surface since):
        the flanks of the way, seen from further back, must still be remembered when the
        vehicle reaches them, after a look round (30 s: the look at the start alone takes
        7 s). The odometry that placed it drifts only while the wheels turn, so standing
        still (a wait for a walker, a look with the head) ages nothing
        (:mod:`agent.control.memory_clock`).
    record_seen
        Record the vector's *seen* profiles (``seen_range_m``: what the scans saw clear,
        movers taken as still) rather than the aged ones (``free_range_m``: what is left of
        it once a mover could have entered), where the agent gives them. On (this release;
        the history below). Measured on
        evaluate's random runs 0-47 of seed 0, ``active``: with perfect odometry and no
        walkers, tasks done 0 (off) against 8 (on); with the odometry's drift and the
        walkers, 0 and 0, collisions by the vehicle 4 (all walkers) against 13 (12 walkers:
        the vehicle that moves more backs or turns into walkers it does not watch; 1 a
        doorway's edge, the drift over 11.6 m). Re-measured with walls inflated across
        their line (``across_sigma_m``) and the memory aged only while moving, runs 0-95:
        with drift and walkers, 0 tasks done either way, collisions 17 (11 by the vehicle,
        all walkers) off against 45 (24 by the vehicle, 1 of them static) on; with perfect
        odometry and no walkers (on), 23 done, none colliding. Worth turning on once the
        vehicle guards the space it moves into against walkers. Re-measured with walkers
        on their trails' lines, looks with the head and unknown space kept beyond the near
        limit (runs 0-47, ``active``, the odometry's drift, the drift estimate on when on):
        no walkers, 1 task done (off) against 8 (on), the median distance left to the goal
        3.8 m against 1.7 m, no collision either way; with the walkers, 1 done on, and 5
        collisions with walkers, 3 of them by the vehicle (runs 12, 44, 45; run 45 at
        0.5 m/s, 12 s in, a walker from 50-70° to its left that no scan had seen). Kept off
        then: the aged profile was what kept the vehicle from driving fast where a walker
        it had not seen might step in. Turned on with the walks kept across tracks
        (:class:`agent.control.walk_lines.WalkRegistry`), lost walkers walking on, the head
        asked to look where they may be (``watch_xy``) and the memory's drift limit
        (``memory_drift_rad``): runs 0-47, the defaults otherwise, off / on: tasks done
        0 / 1, progress 0.23 / 0.30, mean speed 0.046 / 0.051 m/s, collisions 0 / 2 (both
        walkers walking into the standing vehicle; none by the vehicle).
    memory_drift_rad, drift_ratio_rad_per_m, drift_track_per_rad, drift_slip_rad2_per_m
        Nor is space kept once the odometry's heading may have drifted by more than
        ``memory_drift_rad`` (1σ) since it was seen (:class:`agent.control.memory_clock.
        DriftClock`). The drift's rates are the base's odometry model's
        (:mod:`agent.sim.odometry`): the right-minus-left scale error's σ (1.5 %) over the
        track (0.5 m), 0.03 rad per metre driven (signed: driving back undoes it); the
        track's error, 0.02 per radian turned (signed: a look round and back undoes it); the
        wheels' slip, 2·1e-5 m²/m over the track squared. 0.05 rad: 1.7 m of straight
        driving, or 2.5 rad of turning one way, ages the memory out; 3σ of it misplaces a
        cell 1 m off by 15 cm. Measured (random run 18 of seed 0, ``active``, the seen
        profiles recorded, no drift limit): the heading 8.6° further off after 2.2 m driven
        in 8 s of moving, and the vehicle, giving way into space remembered from before, met
        a door's jamb. On runs 0-47 of seed 0 (``active``, the seen profiles recorded): no
        limit / 0.05 / 0.02 rad: that collision / none / none, progress 0.32 / 0.30 / 0.14,
        mean speed 0.060 / 0.051 / 0.032 m/s (at 0.02, a third of the commands waited for
        space ahead to be seen again). A base whose odometry does not drift (the tests'
        harness) sets the three rates to 0.
    blind_band_m
        Beside the vehicle, outside the window, a band this wide about the outline would
        count as clear where no possible surface was seen. 1 mm: off. The 0.2 m band
        assumed before (what a rotation on the spot sweeps beyond the outline) was where
        the random worlds' vehicle collisions were: objects in it that the window never
        showed (``evaluate --random 12 --policy forward``: 8 collisions with it, 0
        without).
    silent_range_m, looked_elsewhere_rad
        In the window, within this of the centre of scanning and beyond the near limit, a
        sector the newest profile leaves at 0 is *silent*: the scan crossed it and no light
        came back. Any surface of the worlds there would have returned a valid reading (eq.
        6.10-6.11: the darkest, reflectivity 0.2 seen 84° off its normal, returns at 1.0 m
        3.2 times the 146 pA that vouches for a no-return at 1.8 m, i.e. the 0.47 nA of a
        valid sample), and a valid reading clears its beam from the centre of scanning, so
        the profile would not be 0 there. 1.0 m: the window is as wide as the vehicle
        (±0.3 m) from 0.85 m on, so silence shows the corners' way ahead; the agent's own
        profile cannot in open space, where a no-return is vouched for only in the right
        26° of the window (the left 14.6° could hide a missing part, ``free_space``).
        The window is the vector's ``scan_window_rad`` where the agent gives it (any pan,
        the head slewing or not), narrowed to the profile's sectors wholly
        inside it (each reaches half a 1° step past its bearing: the forward ±20° gives
        ±19.5°, as ``window_half_rad``). Where it does not (an older agent, or one that did
        not know where the scan's beams went), the forward window, and silence counts as
        clear only while the head is taken to scan it: not for 2 s after the profile shows
        it looked elsewhere (a sector lit beyond ``looked_elsewhere_rad`` plus the vehicle's
        own turn of the last 0.5 s).
    footprint_memory_s, start_clear_m
        Where the vehicle's outline was within ``footprint_memory_s`` of moving nothing
        static stands;
        at the start, the disc of the circumradius plus ``start_clear_m`` about the start
        pose's centre counts so: the random worlds keep the start's turning circle
        ``START_CLEARANCE_M`` (0.42 m) clear of everything (:mod:`agent.sim.taskgen`), the
        ring the sensor cannot see from the start (a start pose is a place the vehicle was
        put, whose surroundings its operator knows).
    suspect_depth_m, suspect_max_range_m, suspect_memory_s
        Past the end of a profile's sector, this deep, a surface may stand (the agent clears
        a beam to 3σ + 3 cm short of a return); a sector ending beyond
        ``suspect_max_range_m`` ends where a dark surface would not return light (about
        1.8 m), not at a surface, and marks nothing; nor does one ending nearer than the
        near limit, which ends where no beam has yet passed (the agent clears the space
        nearer than 0.4 m only along beams that returned from further), not at a surface.
        Such a mark is forgotten after ``suspect_memory_s`` unless seen again: a static
        surface seen that often is a track by then (3 hits in 5 scans), so an old mark was
        an untracked mover or a phantom. A tracked mover's own hits mark nothing.
    near_limit_m, far_limit_m
        The sensor's depth of field: nothing nearer than 0.4 m to the centre of scanning
        returns light, and the profile never claims beyond 2.5 m.

    Obstacles (:mod:`agent.control.obstacles`)
    ------------------------------------------
    covariance_sigmas
        Obstacles are inflated by this many standard deviations of their position along
        its worst axis: 3σ leaves 0.13 % of a one-dimensional Gaussian error beyond it in
        the direction of the vehicle.
    inflation_cap_m
        At most this much inflation from the covariance: a track coasting out of view grows
        its σ (up to 0.5 m before the tracker drops it), and 3σ of that would close every
        passage; beyond 0.25 m the obstacle stays where it is believed to be.
    mover_inflation_cap_m
        A mover's inflation cap (:mod:`agent.control.obstacles`): 1.5 m, 3σ of where a
        walker whose velocity is known to 0.33 m/s (1σ) may be at the end of the 1.5 s
        horizon. Beyond it the track knows too little to say where the walker is going,
        and the capsule would shut every way near it.
    obstacle_margin_m
        Added to every obstacle: perimeter points and cells are 5 cm apart.
    mover_speed_m_s
        An obstacle whose velocity estimate exceeds this is a mover (a static track's
        velocity noise is a few mm/s), if the estimate is significant (below).
    mover_significance
        A mover's speed is at least this many times its velocity's σ along its direction.
        Measured in ``evaluate``'s random runs 0-11 of seed 0 (``active``, the odometry's
        drift; the vector's moving cylinders matched to the true walkers within 0.5 m):
        real walkers' tracks had speed/σ 0.84 at the median (σ 0.48 m/s: most tracks are
        young, their velocity near its 0.5 m/s prior), 85 % above 0.5; the others (static
        pillars whose track's constant-velocity model had won, velocity 0.1 ± 0.56 m/s)
        0.31, 9 % above 0.5. Counted as movers, those were kept on their walks for 30 s
        (:mod:`agent.control.walkways`) and stopped the vehicle: in runs 0-47 with no
        walkers at all, a quarter of its commands were "yielding".
    mover_horizon_s
        A mover is swept along its velocity this long from the vector's stamp: the braking
        envelope at full speed (1.1 s) plus the vector's validity (0.3 s), rounded up.
    walkway_memory_s, walkway_reach_m, walkway_cell_m, walkway_seen_age_s
        A mover that leaves the vector (its track deleted, or lost where the sensor cannot
        see it: nearer than 0.4 m to the centre of scanning, beside the window) walks on:
        it is kept as the places on its line where it may be (:mod:`agent.control.walkways`),
        on cells of ``walkway_cell_m`` out to ``walkway_reach_m`` either way, for at most
        ``walkway_memory_s`` after it was last in a vector. 30 s: kept 2 s (as before) the
        walkers that met the vehicle had been lost 5-10 s before; 3 m: beyond it the
        walker has walked off its line's known part (the worlds' walks are 1-5 m). A cell
        leaves the set when the vector's seen profile (scans of the last
        ``walkway_seen_age_s``, the agent's ``SEEN_MAX_AGE_S``) holds it and the cells the
        walker could have walked from since clear.

    walk_trail_n, walk_fit_points, walk_fit_span_m
        A mover's line is fitted to the last ``walk_trail_n`` places of its walk (40: 4 s
        of one track, a walk's length at a walker's pace), the places of every track of
        the same walker (:class:`agent.control.walk_lines.WalkRegistry`), once it has at
        least ``walk_fit_points`` (5) spanning ``walk_fit_span_m`` (0.3 m) along it
        (:mod:`agent.control.walk_lines`); fewer, or a shorter span (the fits' errors had
        a heavier tail below 0.4 m), and its velocity's direction is used. A walk no
        track has joined for ``walkway_memory_s`` is forgotten. Measured (runs 0-47 of
        seed 0, ``active``, defaults), a walk per track against one across tracks:
        "yielding" 56 % → 39 % of the commands, mean speed 0.038 → 0.051 m/s, tasks done
        0 → 0, collisions 0 → 2 (walkers walking into the standing vehicle, one never in a
        vector before it was 0.8 m away).
    walkway_unfitted_memory_s
        How long a walker whose line could not be fitted is kept on its walk (its
        velocity's line, known to tens of degrees: a capsule at the 1.5 m cap). 30 s, as
        any walker: kept 4 s (runs 0-47 of seed 0, ``active``, defaults), the vehicle
        yielded 39 % of its commands rather than 48 % and moved at 0.045 m/s rather than
        0.040, but met one more walker while moving (run 17).
    watch_reach_m, watch_points
        The places where remembered walkers may be (their walks' possible cells) within
        this of the vehicle, nearest first, at most this many, go to the head's planner as
        ``vehicle_state``'s ``watch_xy``: a look there finds the walker (tracked again, on
        its line) or frees the walk it is not on. 3 m: the walks' reach
        (``walkway_reach_m``) and a little beyond the far limit from the head; 48 cells:
        4.8 m of walk, more than the sensor's reach along one.
    turn_watch_m
        Within this of where the task will have it turn on the spot (a park's goal, the
        docking line's start), the vehicle also asks the head to look at the ring its
        corners sweep there (``watch_xy``): from the turn's place, the ring's cells beside
        the body lie nearer the centre of scanning than the 0.4 m near limit, and a turn
        blocked by them unknown stood there until the time ran out (random runs 9, 14, 15,
        34 and 47 of seed 0, no walkers: parked within 0.2 m, facing off by more than the
        tolerance). 2.5 m: the sensor's far limit. With it, a turn that keeps the way it
        took once the other is blocked, backs off and looks when blocked both ways, and a
        footprint memory that holds what the corners swept between vectors
        (:meth:`~agent.control.clearance.ClearanceMap.add_footprint`), runs 0-47 of seed 0
        (``active``, no walkers) did 10 tasks rather than 3; with walkers, 0 rather than 1
        (yielding 47 % of the commands: few came near their goals).

    Giving way (:mod:`agent.control.give_way`)
    ------------------------------------------
    walkway_min_sightings
        Only a mover that was one in at least this many vectors is kept on its walk once it
        leaves the vector. Measured in ``evaluate``'s random runs 0-15 of seed 0 with the
        walkers removed (``active``, the odometry's drift): 16 tracks of static pillars
        passed for movers (``mover_significance``) in 2 vectors at the median, 1 of 16 in 5
        or more; the real walkers' tracks (runs 0-11, walkers in) in 6 at the median, 3 at
        the 10th percentile. Kept 30 s on their walks, those few vectors made a quarter of
        the vehicle's commands "yielding" with no walker in the world. With both rules
        (runs 0-47, no walkers, drift, the seen profiles recorded): "yielding" 24 % → 4 %
        of the commands, mean speed 0.078 → 0.092 m/s, tasks done 1 → 1.
    walkway_standing_s
        A remembered walker whose own track is in the vector again, not moving and seen in
        the scans of the last ``walkway_seen_age_s``, for this long, stands where it is seen
        and is forgotten: in the demo world a post's track (0.15 m, 2.2 m off) passed for a
        mover at 0.8 m/s in three vectors while the vehicle turned, and kept on a 7 m walk
        through the post, inflated to the 1.5 m cap, it held the vehicle "yielding" for
        30 s while the same track stood static in every vector. 1 s: ten vectors, where a
        walker turning at its walk's end is seen slow for one or two.
    give_way_margin_m
        The outline is out of a walker's walk when every point of it lies this far beyond
        the walker's surface from the walker's line (its velocity's): a walker's heading
        wavers. The line's own error (the tracks' velocities are known to tens of degrees
        near the vehicle) is not in it: a way out is only tried when the walker comes, and
        the capsules, inflated by that error, still stop the vehicle wherever it may be.
    give_way_reserve_s
        A way out counts only when it is done this long before the walker comes (the
        command's period and latency, and the walker's speed known to tens of cm/s).
    give_way_horizon_s
        Only walkers that would meet the outline within this long are given way to: a walk
        that crosses the vehicle far off is the planner's to weigh, not a reason to move now.
    give_way_lead_s
        The vehicle gives way as soon as it stands in a walk whose walker may come (either
        way: walkers turn back at their walk's end) within this long, plus the time to
        leave the walk from rest, plus ``give_way_reserve_s``, not only once a walker's
        capsule reaches it: with the capsule's 1.5 s of warning, a way out done in time was
        rarely left. Shorter than the planner's lead (``horizon_s``, below), so that a
        vehicle the planner lets into a walk is not sent straight back out of it.
    walk_charge_s
        The local planner charges an arc that ends in such a walk, its lead the arc's
        horizon (``horizon_s``), this many seconds, and as many again per metre the outline
        lies in it (:mod:`agent.control.local_planner`): more than any arc's gain in
        progress (at most its horizon, 1.5 s), so the vehicle waits beside a walk rather
        than in it, and a vehicle in one takes the arc that leaves it soonest.

    Navigation field (:mod:`agent.control.navigation`)
    --------------------------------------------------
    nav_cell_m, nav_margin_m, nav_max_cells
        The cost-to-go grid: 10 cm cells over the box of vehicle and goal plus this margin
        on every side (room to go round what lies between), at most this many cells a side
        (the cell grows beyond).
    nav_period_s
        The field is recomputed at most this often while the map changes (each costs a
        few ms); at once when the goal moves.
    nav_clearance_m
        Cells nearer than the vehicle's half-width plus this to an obstacle are lethal
        (a disc of the half-width cannot pass there).
    nav_lethal_cost, nav_near_cost, nav_unknown_cost
        Cost per metre of a lethal cell (finite, so the field still leads out of one), the
        extra cost at the lethal boundary falling to 0 at the circumradius (rotating there
        is not possible), and the factor for space never seen clear (passable, but known
        clear space is preferred).

    Planning (:mod:`agent.control.local_planner`, :mod:`agent.control.dwa`)
    ----------------------------------------------------------------------
    horizon_s
        Each candidate arc is rolled out this long and scored on the field where it ends.
    heading_weight
        The score's weight on the heading error at the arc's end (seconds per radian
        of turn left to do, times this).
    clearance_weight, clearance_want_m
        A candidate whose free travel is below ``clearance_want_m`` is charged this many
        seconds per metre short.
    dwa_heading, dwa_clearance, dwa_velocity, dwa_speeds, dwa_yaw_rates
        The dynamic window approach's weights on its three normalised terms and its samples
        of the window.

    Goals
    -----
    goal_reach_m
        goto and park aim this close to the goal in ``odom`` (the run is scored in the
        true world, which the odometry's drift moves the goal in; the tolerance is left
        to the drift), or at ``tolerance_m`` / 3 if that is smaller.
    park_yaw_rad
        park turns to the goal's heading within this, or ``tolerance_rad`` / 3.
    final_approach_m
        Within this of the goal, with the field's cost no more than the straight distance
        (nothing in between), the vehicle steers straight at the goal.

    Docking (:mod:`agent.control.docking`)
    --------------------------------------
    dock_search_m, dock_search_wait_s
        The docking target is the kind-4 obstacle nearest the goal, no further than this
        from it; until one is seen, the vehicle drives to within 0.6 m beyond the docking
        pose's distance of the goal (``dock_distance_m`` plus the head's offset: 1.4 m) and
        faces it, and after ``dock_search_wait_s`` with none in sight, to that distance
        (0.8 m): the goal in ``odom`` is only as good as the drift estimate.
    dock_viewpoint_s
        Nothing seen from there either, the vehicle searches from another side of the goal
        (:mod:`agent.control.docking`, *searching*), driving there for at most this long
        (30 s: a detour round a wall through the next door) before it searches from where
        it stands.
    dock_line_m
        The final approach follows the face's normal this far (the vehicle lines up
        before).
    dock_align_cross_m, dock_align_along_m
        The vehicle turns onto the docking line where it stands when base_link is within
        these of the line's start, across and along the line (and keeps turning while
        within 2.5 × them), and starts along the line when it is within 2.5 ×
        ``dock_align_cross_m`` of it, facing it within 3°: the line follower takes up the
        rest (its curvature, at most 3 /m, takes up 0.125 m across in about 0.4 m). (At
        3 cm of the start point, and 8 cm to go on turning, the vehicle chased the start
        while the target's estimate moved it, 0.11 m across the line as more of the face
        was seen, and turned back and forth before it: random run 60 of seed 0, no
        walkers, timed out so, and docks now, as does run 28.)
    dock_speed_m_s, dock_gain_per_m
        The final approach's speed, and the line follower's natural wavenumber: the
        cross-track error decays as exp(−ω s) critically damped (ω = 10 /m: e⁻⁵ over 0.5 m).
    dock_position_m, dock_yaw_rad
        Stopped within these (head position along and across the line, heading) the vehicle
        has docked; beyond them at the line's end it backs off and tries again.
    dock_face_gap_m
        On the docking line, the look-ahead row (``look_ahead_m``) stays this far short of
        the face at the stop: the cells next to a surface are never known clear.

    Looking
    -------
    look_at_start
        Before it first moves, the vehicle turns on the spot all round (three thirds of a
        turn, about 7 s): with the window fixed ahead, that is how it sees what lies about
        it. Off only for tests of the rules themselves.
    look_ahead_m, head_pans_memory_s
        With a head that pans (a vector's scanned window off the heading within the last
        ``head_pans_memory_s``, 30 s: a head that pans may look ahead for a while), a
        forward motion goes no further than keeps a row of
        points ``look_ahead_m`` ahead of the bumper out of unknown space
        (:mod:`agent.control.clearance`): 0.3 m, where the head's near limit (0.4 m from
        the centre of scanning, 0.1 m behind the bumper) ends. Space nearer the bumper than
        that is never seen from where the vehicle stands; a vehicle that crept on into
        unknown space ahead stopped with it there, and could only back off, look and try
        again (measured: random run 0 of seed 0, no walkers, perfect odometry, 60 s of
        such rounds at one place). Stopped short of it, the head can look at it. A head
        that does not pan never sees beside the window there, so not without one.
        The world's goal (and a park's heading) is carried into ``odom`` by the drift the
        static obstacles show (:mod:`agent.control.landmarks`); off, it is taken in
        ``odom`` as given (the odometry's drift then moves it).
    look_stand_s, head_panned_rad
        Each look (at the start, and after backing off) begins with the vehicle standing
        this long (2 s) while the head looks; a head that pans (a vector's scanned window
        centred at least ``head_panned_rad``, 0.5 rad, off the heading within the last
        ``head_pans_memory_s``) sees ±110° of the heading from where the vehicle stands, and the
        vehicle then turns only to face the way ahead, not all round: each full turn on the
        spot costs about 7 s and, with the odometry's track error (2 %), about 7° of
        heading, which misplaces all that was remembered before it (measured: a heading
        31° off after the turns of random run 18's 89 s, and a door's jamb remembered
        clear where it stood). A head that does not pan (``forward``) is turned all round
        as before.
    back_off_m, back_off_speed_m_s
        When navigating makes no progress, before it looks round, the vehicle backs off
        this far (straight, at this speed, where the braking envelope allows: into space it
        knows clear, such as where it came from). The space just ahead of its bumper lies
        nearer the centre of scanning than the 0.4 m near limit, where no look can see it;
        once forgotten (or never seen, after a turn) only distance shows it again. 0.35 m
        brings the bumper's first 0.3 m beyond the near limit.
    """

    period_s: float = 0.05
    latency_s: float = 0.05
    cell_m: float = 0.05
    memory_size_m: float = 8.0
    sweep_step_m: float = 0.05
    sweep_reach_m: float = 1.0
    outline_spacing_m: float = 0.05
    stop_margin_m: float = 0.025
    window_half_rad: float = math.radians(19.5)
    clear_memory_s: float = 30.0
    blind_band_m: float = 0.001
    silent_range_m: float = 1.0
    looked_elsewhere_rad: float = math.radians(35.0)
    footprint_memory_s: float = 30.0
    start_clear_m: float = 0.42
    suspect_depth_m: float = 0.15
    suspect_max_range_m: float = 1.5
    suspect_memory_s: float = 5.0
    near_limit_m: float = 0.4
    far_limit_m: float = 2.5
    covariance_sigmas: float = 3.0
    inflation_cap_m: float = 0.25
    mover_inflation_cap_m: float = 1.5
    obstacle_margin_m: float = 0.03
    mover_speed_m_s: float = 0.05
    mover_significance: float = 0.5
    mover_horizon_s: float = 1.5
    walkway_memory_s: float = 30.0
    walkway_reach_m: float = 3.0
    walkway_cell_m: float = 0.1
    walkway_seen_age_s: float = 0.5
    walkway_min_sightings: int = 3
    walkway_standing_s: float = 1.0
    walk_trail_n: int = 40
    walk_fit_points: int = 5
    walk_fit_span_m: float = 0.3
    walkway_unfitted_memory_s: float = 30.0
    watch_reach_m: float = 3.0
    watch_points: int = 48
    turn_watch_m: float = 2.5
    give_way_margin_m: float = 0.15
    give_way_reserve_s: float = 0.5
    give_way_horizon_s: float = 6.0
    give_way_lead_s: float = 1.0
    walk_charge_s: float = 10.0
    nav_cell_m: float = 0.1
    nav_margin_m: float = 3.0
    nav_max_cells: int = 200
    nav_period_s: float = 1.0
    nav_clearance_m: float = 0.05
    nav_lethal_cost: float = 50.0
    nav_near_cost: float = 2.0
    nav_unknown_cost: float = 1.3
    horizon_s: float = 1.5
    heading_weight: float = 0.6
    clearance_weight: float = 2.0
    clearance_want_m: float = 0.4
    dwa_heading: float = 0.8
    dwa_clearance: float = 0.2
    dwa_velocity: float = 0.1
    dwa_speeds: int = 5
    dwa_yaw_rates: int = 9
    goal_reach_m: float = 0.05
    park_yaw_rad: float = math.radians(1.0)
    final_approach_m: float = 0.8
    dock_search_m: float = 1.5
    dock_search_wait_s: float = 5.0
    dock_viewpoint_s: float = 30.0
    dock_line_m: float = 0.6
    dock_align_cross_m: float = 0.05
    dock_align_along_m: float = 0.2
    dock_speed_m_s: float = 0.15
    dock_gain_per_m: float = 10.0
    dock_position_m: float = 0.0015
    dock_face_gap_m: float = 0.2
    dock_yaw_rad: float = math.radians(0.2)
    look_at_start: bool = True
    look_stand_s: float = 2.0
    look_ahead_m: float = 0.3
    head_pans_memory_s: float = 30.0
    correct_drift: bool = True
    head_panned_rad: float = 0.5
    record_seen: bool = True
    memory_drift_rad: float = 0.05
    drift_ratio_rad_per_m: float = 0.03
    drift_track_per_rad: float = 0.02
    drift_slip_rad2_per_m: float = 8e-5
    back_off_m: float = 0.35
    back_off_speed_m_s: float = 0.15

    def __post_init__(self) -> None:
        for field in fields(self):
            if field.name in ("look_at_start", "record_seen", "correct_drift"):
                continue
            value = float(getattr(self, field.name))
            if field.name in _MAY_BE_ZERO and math.isfinite(value) and value == 0.0:
                continue  # a base whose odometry does not drift
            if not math.isfinite(value) or value <= 0.0:
                raise ValueError(
                    f"ControllerSettings.{field.name} must be positive and finite, got {value!r}"
                )
        if self.dwa_speeds < 2 or self.dwa_yaw_rates < 2:
            raise ValueError("ControllerSettings.dwa_speeds and dwa_yaw_rates must be >= 2")
        if self.window_half_rad >= math.pi:
            raise ValueError("ControllerSettings.window_half_rad must be below pi")
