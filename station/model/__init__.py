"""The measurement model: z = a^T v + b (docs/conventions.md), its frames, constants, the Earth, the sensor output chain and the named effects. Imports nothing else of the station."""
