"""Scoring against simulation truth (benchmarks and evaluation only): GOSPA, track-to-truth
association, NEES, id switches, free-space errors. No agent stage imports it.

* :mod:`agent.scoring.frames`: poses, and where a true point lies in the drifting ``odom``;
* :mod:`agent.scoring.gospa`: the GOSPA metric and its optimal assignment;
* :mod:`agent.scoring.nees`: NEES and its χ² interval over runs;
* :mod:`agent.scoring.identity`: id switches and fragmentations;
* :mod:`agent.scoring.truth`: the true corners, faces and cylinders, and what a scan hits;
* :mod:`agent.scoring.free_space`: a free-space profile against the true world;
* :mod:`agent.scoring.tracking`: all of it, scan by scan and run by run, for a tracker.
"""
