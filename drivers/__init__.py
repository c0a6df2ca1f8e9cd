"""Instrument drivers: one abstract interface per instrument family, transports behind it (issue 3)."""
