"""Calibration solvers: arrays in, arrays out, no file or device I/O (closed forms, maximum
likelihood, uncertainty)."""
