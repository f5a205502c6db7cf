"""Track identity against the truth: id switches and fragmentations, scan by scan.

Each scan gives the pairs (track id, truth id) of an assignment (the GOSPA assignment of
:mod:`agent.scoring.gospa`: confirmed tracks to the truth objects nearer than ``c``) and the
ids of every track alive in that scan (any status). Each truth object remembers the track
last assigned to it, each track the truth object last assigned to it. A pair (track ``i``,
truth ``j``) is

* an **id switch** when track ``i`` was last assigned to another truth object (its track
  changed object), or when ``j`` was last assigned to another track ``k`` that is still
  alive (another id took it over): counted once per pair, whichever of the two it is;
* a **fragmentation** when it is not a switch and ``j`` was last assigned to another track
  that is no longer alive (the object is tracked under a new id after its track was
  deleted);
* otherwise a continuation (or the object's first track).

Scans in which an object is not assigned (out of view, missed) change nothing: an object
re-associated with its old track after a gap is a continuation.
"""

from __future__ import annotations

from collections.abc import Iterable

__all__ = ["IdentityLedger"]


class IdentityLedger:
    """Counts id switches and fragmentations over a run (module docstring)."""

    def __init__(self) -> None:
        self.id_switches = 0
        self.fragmentations = 0
        self._track_of: dict[int, int] = {}  # truth id -> track id last assigned
        self._truth_of: dict[int, int] = {}  # track id -> truth id last assigned

    def last_truth(self, track: int) -> int | None:
        """The truth object last assigned to ``track`` (None: never)."""
        return self._truth_of.get(track)

    def update(self, pairs: Iterable[tuple[int, int]], alive_tracks: Iterable[int]) -> None:
        """One scan: ``pairs`` of (track id, truth id) assigned in it (each id at most once),
        ``alive_tracks`` every track id present in the scan's tracks."""
        alive = set(alive_tracks)
        pairs = list(pairs)
        for track, truth in pairs:
            before = self._track_of.get(truth)
            switched = self._truth_of.get(track, truth) != truth or (
                before is not None and before != track and before in alive
            )
            if switched:
                self.id_switches += 1
            elif before is not None and before != track:
                self.fragmentations += 1
        for track, truth in pairs:
            self._track_of[truth] = track
            self._truth_of[track] = truth
