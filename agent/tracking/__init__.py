"""Feature tracking: one Kalman filter per feature in ``odom``, predicted with the vehicle's
motion and its odometry uncertainty; gating, global assignment, initiation, confirmation and
deletion by expected visibility."""


def warm_up() -> None:
    """Load the compiled kernels, so that the first scan does not pay for it (on
    a new machine the first call compiles them, a few seconds; then they load from the disk
    cache in a fraction of a second)."""
    from agent.tracking import drift_kernels, tracker_kernels, visibility_kernels

    drift_kernels.warm_up()
    visibility_kernels.warm_up()
    tracker_kernels.warm_up()
