"""Friction estimation: online, by inverse dynamics of each rig with causal differentiation; and rate-and-state's
reduction of velocity steps and holds (rsf_programme, rsf_fit)."""
