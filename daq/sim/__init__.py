"""Simulated rigs: the integrator, the rigs' adapters over daq/physics, effect selection, instruments, the run driver."""
