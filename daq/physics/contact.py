"""Contact quantities every rig reports beside its state (the simulator's ground truth)."""

from __future__ import annotations

from enum import IntEnum

from .jit import helper


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


@helper
def set_aux(aux, f, n, mu, v_drive, v_cmd, v_rel, n_inst, acc):
    """Fill one row of AUX (every rig reports the same quantities, in this order)."""
    aux[AUX.F] = f
    aux[AUX.N] = n
    aux[AUX.MU] = mu
    aux[AUX.V_DRIVE] = v_drive
    aux[AUX.V_CMD] = v_cmd
    aux[AUX.V_REL] = v_rel
    aux[AUX.N_INST] = n_inst
    aux[AUX.ACC] = acc
