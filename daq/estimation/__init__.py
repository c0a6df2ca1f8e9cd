"""Online friction estimation: inverse dynamics of each rig with causal differentiation."""
