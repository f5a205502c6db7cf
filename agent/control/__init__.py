"""The vehicle controller's logic: local planning on the environment vector, parking, docking,
and the stop on stale or untrusted data. Pure code: arrays and a time in, commands out."""
