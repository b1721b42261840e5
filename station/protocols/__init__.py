"""Calibration protocols: what the station asks of the devices and the technician, step by step.

`rotary` (gyros on a rotary table, Rupniewski Section IV, Eq. 18).
"""
