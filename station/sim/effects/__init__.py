"""Named effects of the simulator, one module each, all off by default (docs/simulator.md)."""
