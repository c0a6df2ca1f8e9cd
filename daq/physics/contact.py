"""Contact quantities every rig reports beside its state (the simulator's ground truth)."""

from __future__ import annotations

from enum import IntEnum


class AUX(IntEnum):
    """Slots of the auxiliary output each rig's right-hand side fills at every evaluation."""

    F = 0  # friction force on the body [N] (belt-ndof: dimensionless f times F0)
    N = 1  # normal load the friction law used [N]
    MU = 2  # friction coefficient [-]
    V_DRIVE = 3  # actual belt/drum surface speed [m/s]
    V_CMD = 4  # commanded belt/drum surface speed [m/s]
    V_REL = 5  # relative sliding velocity body - drive [m/s]
    N_INST = 6  # instantaneous normal load (what a gauge would read) [N]
    ACC = 7  # acceleration of the body at the contact, along the sliding direction [m/s^2]


N_AUX = len(AUX)
