"""Calibration files: one unit's calibration as JSON, validated on load, its format in its
docstring (calfile), and several calibrations of one unit combined into one with their
repeatability (combined)."""
