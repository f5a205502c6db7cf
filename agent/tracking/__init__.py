"""Feature tracking: one Kalman filter per feature in ``odom``, predicted with the vehicle's
motion and its odometry uncertainty; gating, global assignment, initiation, confirmation and
deletion by expected visibility."""
