"""Capture simulation and ground truth: scenes through the sensor model into camera data."""
