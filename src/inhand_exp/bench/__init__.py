"""Benchmarks of the physics core: control-loop speed and primitive success rates."""
