"""The sensor planner's domain: the free-space profile, the environment vector assembled from
tracks and free space, and the head policies that choose where to look."""
