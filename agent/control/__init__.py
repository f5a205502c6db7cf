"""The vehicle controller's logic: local planning on the environment vector, parking, docking,
and the stop on stale or untrusted data. Pure code: arrays and a time in, commands out.

* :mod:`~agent.control.controller`: :class:`Controller` (the three calls the ``vehicle``
  stage makes), its output and the task logic (goto, park, dock);
* :mod:`~agent.control.view`: the environment vector as arrays, and when it may be used;
* :mod:`~agent.control.clearance`: known clear space and the braking-envelope rule;
* :mod:`~agent.control.obstacles`: obstacles as capsules inflated by their covariance,
  movers swept along their velocity;
* :mod:`~agent.control.navigation`: the cost-to-go toward the goal over a remembered map;
* :mod:`~agent.control.local_planner`: arcs scored on that field (the default planner);
* :mod:`~agent.control.dwa`: the dynamic window approach (the baseline);
* :mod:`~agent.control.docking`: the docking target, the pose to stop at, the last approach;
* :mod:`~agent.control.geometry`, :mod:`~agent.control.settings`: plane geometry and
  every constant with its reason; ``*_kernels``: the compiled loops.
"""
