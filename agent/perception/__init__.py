"""Perception: the filter (:mod:`agent.perception.filtering`) and the feature extractor
(:mod:`agent.perception.features`), and their scoring against the simulation's truth
(:mod:`agent.perception.evaluation`)."""

from __future__ import annotations

from agent.perception import features, filtering

__all__ = ["warm_up"]


def warm_up() -> None:
    """Load every compiled perception kernel, so that the first scan does not pay for it.

    The first use on a machine compiles them (about 15 s, which ``run.py`` does at install);
    after that a new process loads them from the disk cache in about a third of a second.
    """
    features.warm_up()
    filtering.warm_up()
