"""Scoring against simulation truth (benchmarks and evaluation only): GOSPA, track-to-truth
association, NEES, id switches, free-space errors. No agent stage imports it."""
