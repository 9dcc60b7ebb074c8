"""Geostationary attitude control with reaction wheels (paper B)."""
