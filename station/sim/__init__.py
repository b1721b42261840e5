"""Digital twin of the calibration bench: sensor unit, rotary table, poses, named effects.

The simulator is the truth source for the virtual devices, the demo and the tests
(docs/simulator.md). Everything is deterministic from a numpy Generator seed.
"""
