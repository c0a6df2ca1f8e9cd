"""Data acquisition, simulation and friction-model analysis for dry-friction test rigs."""

__version__ = "0.1.0"
