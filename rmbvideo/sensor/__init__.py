"""Sensor physics: binning of real 1-bit data, RMB readout, emission simulator and theory."""
