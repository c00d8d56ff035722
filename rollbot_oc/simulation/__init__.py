"""Simulation: the plant (full dynamics, motor limits, floor), its sensors and the onboard estimation."""
