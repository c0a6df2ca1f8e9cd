"""Simulated instruments served over real pseudo-terminals and python-can buses (issue 3)."""
