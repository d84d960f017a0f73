"""Rendering: light-stage scenes and polarization image output."""
