"""Virtual benches: every device of a bench simulated behind its real wire protocol (rotary,
hand)."""
