"""The measurement model: z = a^T v + b and its least-squares fusion (measurement.py, one array
orientation, docs/conventions.md), frames, physical constants (constants.py), the Earth, the
sensor unit, the one sensor output chain (sensing.py) and the named effects. Imports nothing else
of the station."""
