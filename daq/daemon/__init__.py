"""The operator daemon: acquisition, control socket, ramp runner, the estimator and recorder processes."""
