"""What the model sees of a smooth rig's record (brake-2dof, drum-pendulum: paper 001's brake, paper 002's drum):
which signals it predicts, its drive, and each window's full start state from the measured positions and their
smoothed velocities. The base and its shared parts: data.py.
"""

from __future__ import annotations

import math

import numpy as np

from daq.physics import brake2dof, drum
from daq.physics.contact import AUX
from daq.physics.effects import TAIL
from daq.signals import noise_sigma, sg

from .data import Measured, RigData, clock_at, stick_tail


class BrakeData(RigData):
    drive_channel = "vb"  # the measured drive: belt speed [m/s]
    rig = "brake-2dof"
    velocity_slots = (1, 3)
    position_slots = (0, 2)

    def _prepare(self, rec, t, rate, source):
        x1 = np.asarray(rec.channels["x1"], dtype=float)
        phi = np.asarray(rec.channels["phi"], dtype=float)
        vb = np.asarray(rec.channels["vb"], dtype=float)
        drive_m, drive_c, csrc = self._drive(rec, t, rate, vb, "vb_set")
        sig = {}
        src = {}
        for name, x in (("x1", x1), ("phi", phi)):
            sig[name], src[name] = self._sigma(name, x)
        r = self.cfg.mechanics.r_m
        half = 0.006 if rate >= 500 else 1.5 / rate
        x1d = sg(x1, rate, half, 1)
        y1d = r * sg(phi, rate, half, 1)
        v_rel = x1d - drive_m
        m = Measured(self.rig, source, t, rate, {"x1": x1, "phi": phi}, {"x1": "m", "phi": "rad"}, sig, src,
                     drive_m, drive_c, csrc, self._temp(rec, rate))
        m.v_rel = v_rel
        m.d_abs_v_rel = sg(np.abs(v_rel), rate, half, 1, degree=2)
        mech = self.cfg.mechanics
        load_rate = (mech.k1_N_per_m + mech.k2_N_per_m) * x1d + mech.k2_N_per_m * y1d  # as brake2dof.rhs
        ts, q = stick_tail(v_rel, load_rate, rate, self.cfg)
        # start positions: lightly smoothed at kHz rates; at 100 Hz a local cubic over +-30 ms would bend
        # through the nearest slip (bias ~100 um), while the raw sample is off by the sensor noise only
        pos = (lambda x: sg(x, rate, half)) if rate >= 500 else (lambda x: x)
        m.context = {"x1_smooth": pos(x1), "y1_smooth": r * pos(phi), "x1_dot": x1d,
                     "y1_dot": y1d, "stick_clock": ts, "load_rate": q}
        return m

    def predict(self, sim, states):
        return {"x1": states[..., 0], "phi": states[..., 2] / sim.p[brake2dof.P.r]}

    def output_rates(self, sim, states, dt):
        return {"x1": states[..., 1], "phi": states[..., 3] / sim.p[brake2dof.P.r]}

    def start_state(self, sim, m, i):
        c = m.context
        s = np.zeros(brake2dof.N_STATE)
        s[0], s[1], s[2], s[3] = c["x1_smooth"][i], c["x1_dot"][i], c["y1_smooth"][i], c["y1_dot"][i]
        n = brake2dof.N_MECH
        s[n + TAIL.TS] = clock_at(sim, m, i)
        s[n + TAIL.Q] = c["load_rate"][i]
        s[n + TAIL.TEMP] = m.temp[i] if m.temp is not None else self.cfg.contact.t_ambient_C
        s[n + TAIL.VLAG] = m.drive_measured[i]
        return s


class DrumData(RigData):
    drive_channel = "drum_speed"  # the measured drive: drum speed [rad/s]
    """drum-pendulum: predicts phi and the surface velocity; the runout phase comes from the thrust gauge."""

    rig = "drum-pendulum"
    velocity_slots = (1,)
    position_slots = (0,)

    def _prepare(self, rec, t, rate, source):
        R = self.cfg.mechanics.R_m
        phi = np.asarray(rec.channels["phi"], dtype=float)
        vel = np.asarray(rec.channels["vel"], dtype=float)
        thrust = np.asarray(rec.channels["thrust"], dtype=float)
        wd = np.asarray(rec.channels["drum_speed"], dtype=float)
        drive_m, drive_c, csrc = self._drive(rec, t, rate, R * wd, None)
        sig, src = {}, {}
        for name, x in (("phi", phi), ("vel", vel)):
            sig[name], src[name] = self._sigma(name, x)
        half = 0.003 if rate >= 500 else 1.5 / rate
        w = sg(vel, rate, half, 0) / R
        v_rel = R * w - drive_m
        m = Measured(self.rig, source, t, rate, {"phi": phi, "vel": vel}, {"phi": "rad", "vel": "m/s"}, sig, src,
                     drive_m, drive_c, csrc, self._temp(rec, rate))
        m.v_rel = v_rel
        m.d_abs_v_rel = sg(np.abs(v_rel), rate, half, 1, degree=2)
        # drum angle from the surface travel; its offset from the thrust gauge's runout (one fit per run)
        travel = np.concatenate([[0.0], np.cumsum(0.5 * (drive_m[1:] + drive_m[:-1]) / rate)])
        theta = travel / R
        p_nom, ro = self.cfg.mechanics.thrust_N, self.cfg.mechanics.runout
        rel = thrust / p_nom - 1.0
        a, b = np.linalg.lstsq(np.column_stack([np.sin(theta), np.cos(theta)]), rel, rcond=None)[0]
        theta0 = math.atan2(b, a) if ro > 0 and math.hypot(a, b) > 0.2 * ro else 0.0
        mech = self.cfg.mechanics
        load_rate = mech.k_N_per_m * mech.Rs_m**2 * np.cos(2.0 * phi) * w / R  # as drum.rhs
        ts, q = stick_tail(v_rel, load_rate, rate, self.cfg)
        m.context = {"phi_smooth": sg(phi, rate, half) if rate >= 500 else phi, "w": w, "travel": R * (theta + theta0),
                     "stick_clock": ts, "load_rate": q, "thrust": thrust}
        return m

    def predict(self, sim, states):
        return {"phi": states[..., 0], "vel": sim.p[drum.P.R] * states[..., 1]}

    def synthetic_extras(self, sim, states, aux, channels, rng):
        # the thrust gauge reads the model's normal load (its runout phase is the model's own)
        thrust = aux[:, AUX.N_INST]
        return {"thrust": thrust + rng.normal(0.0, noise_sigma(channels["thrust"]), thrust.size)}

    def start_state(self, sim, m, i):
        c = m.context
        s = np.zeros(drum.N_STATE)
        s[0], s[1] = c["phi_smooth"][i], c["w"][i]
        n = drum.N_MECH
        s[n + TAIL.TS] = clock_at(sim, m, i)
        s[n + TAIL.Q] = c["load_rate"][i]
        s[n + TAIL.TEMP] = m.temp[i] if m.temp is not None else self.cfg.contact.t_ambient_C
        s[n + TAIL.VLAG] = m.drive_measured[i]
        s[n + TAIL.POS] = c["travel"][i]
        return s
