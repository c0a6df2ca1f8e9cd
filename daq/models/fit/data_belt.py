"""What the model sees of a belt-ndof record (paper 000's chain of masses on a belt, or a spring-slider driven through
its spring): its hybrid windows' start modes (stuck or slipping, the static level each mass would break away at),
the stick threshold read from the record, the rate-and-state state at a window's start and the reduction that starts
its fit. The base and its shared parts: data.py. Decision record: docs/decisions/0021-belt-ndof-in-the-model-loop.md.
"""

from __future__ import annotations

import math

import numpy as np

from daq.config import RigConfig
from daq.errors import InputError
from daq.estimation.rsf_fit import fit_law, start_values
from daq.estimation.rsf_programme import events, load_point_travel, plateaus, programme_table
from daq.physics import beltndof
from daq.physics.effects import TAIL, E
from daq.physics.jit import kernel
from daq.signals import noise_sigma, sg
from daq.sim.rigs import SimRig

from .cycle_features import load_cycles
from .data import Measured, RigData

# belt-ndof's model steps per period of the chain's fastest linear mode (BeltData.model_step). Measured on the
# belt seed model, one mass (3.2 Hz), each window of the 750 000-sample bench record simulated at 0.5 ms and at
# the coarser step: see docs/decisions/0023-a-model-rate-for-long-records.md.
STEPS_PER_PERIOD = 100


@kernel
def _rsf_state_tail(v, v_start, dt, dc, v_ref, law, out):
    """Rate-and-state's state psi = ln(v_ref theta / Dc) along the data's slip speed v (>= 0), each sample solved
    exactly with v held (aging: theta relaxes to Dc/v, or grows by dt at rest; slip: psi relaxes to ln(v_ref/v),
    held at rest), from steady state at v_start."""
    v0 = max(v_start, v_ref)
    psi = math.log(v_ref / v0)
    for i in range(v.size):
        out[i] = psi
        vi = v[i]
        k = vi * dt / dc
        if law == 0:  # aging, in theta
            th = dc / v_ref * math.exp(psi)
            if k < 1e-9:
                th += dt
            else:
                ss = dc / vi
                th = ss + (th - ss) * math.exp(-k)
            psi = math.log(v_ref * th / dc)
        elif k > 0.0:
            ss = math.log(v_ref / vi)
            psi = ss + (psi - ss) * math.exp(-k)


RSF_GUESS_EVENTS = 8  # events the rate-and-state start reads (the first; each is a fit of ~10-50 ms)
RSF_SPEED_S = 0.05  # the slip speed the state reads: the data's v_rel averaged over this long (a slip keeps its length)


def rsf_state_at(sim: SimRig, m: Measured, i: int) -> float:
    """Rate-and-state's contact state at sample i for this model (its law, Dc and v_ref): integrated along the
    data's slip speed (cached per parameter set, as the aging clock is). Why not steady state at the drive's speed:
    a window that starts within a few Dc of a velocity step starts with the state of the speed before it."""
    e = sim.e
    law = 1 if e[E.RS_B_SLIP] != 0.0 else 0
    key = ("rsf", law, float(e[E.RS_DC]), float(e[E.RS_VREF]))
    psi = m.aging.get(key)
    if psi is None:
        if len(m.aging) > 64:
            m.aging.clear()
        w = max(1, int(round(RSF_SPEED_S * m.rate)))
        padded = np.pad(np.asarray(m.v_rel, dtype=float), (w // 2, w - 1 - w // 2), mode="edge")
        v = np.abs(np.convolve(padded, np.ones(w) / w, mode="valid"))
        psi = np.empty(m.n)
        v_start = abs(float(np.median(m.v_rel[:max(1, int(m.rate))])))  # the first second's (v_rel is noisy)
        _rsf_state_tail(np.ascontiguousarray(v, dtype=float), v_start, 1.0 / m.rate, float(e[E.RS_DC]), float(e[E.RS_VREF]),
                        law, psi)
        m.aging[key] = psi
    return float(psi[i])


def stuck_by_hysteresis(v_rel: np.ndarray, v_lo: float, v_hi: float) -> np.ndarray:
    """Stuck samples: everything outside the runs of |v_rel| > v_lo that reach v_hi somewhere.

    Why hysteresis: one threshold near the velocity noise cuts a long stick into pieces wherever the noise
    crosses it (seen at a 1 mm/s drive: sticks of 0.3 s read as runs of 0.02-0.2 s), and a window that starts
    with a stick clock that short breaks away far too early once static friction ages with stick time. A real
    slip is fast; noise that crosses v_lo but never v_hi is still a stick."""
    above = np.abs(v_rel) > v_lo
    edges = np.diff(np.concatenate([[0], above.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    stuck = np.ones(v_rel.size, dtype=bool)
    big = np.abs(v_rel) > v_hi
    for a, b in zip(starts, stops):
        if big[a:b].any():
            stuck[a:b] = False
    return stuck


def stuck_time(stuck: np.ndarray, rate: float) -> np.ndarray:
    """Per sample, how long the contact has been stuck without a break [s] (0 where it slips)."""
    idx = np.arange(stuck.size)
    last_slip = np.maximum.accumulate(np.where(stuck, -1, idx))  # the latest slipping sample so far (-1: none)
    return np.where(stuck, (idx - last_slip) / rate, 0.0)


def last_stick(stuck_s: np.ndarray) -> np.ndarray:
    """Per sample, how long the stick that ended last before it lasted [s] (0 before the first stick ended)."""
    ended = np.flatnonzero((stuck_s[1:] == 0.0) & (stuck_s[:-1] > 0.0)) + 1  # first slipping sample after a stick
    out = np.zeros(stuck_s.size)
    if ended.size:
        which = np.searchsorted(ended, np.arange(stuck_s.size), side="right") - 1  # the latest end at or before
        held = which >= 0
        out[held] = stuck_s[ended[which[held]] - 1]
    return out


class BeltData(RigData):
    """belt-ndof (paper 000): predicts every mass's position; a window starts with each mass's stick/slip mode.

    Why a hybrid start: paper 000's law is discontinuous, so its simulator keeps each mass's mode (stuck or
    slipping), its stick clock and the break-away level beside the state vector (daq/physics/beltndof.py).
    A window's start sets them from the data: a mass whose smoothed velocity is within v_stick of the belt's
    is stuck, stuck since the first sample of that run (the stick clock the stick-time effect reads); a mass
    that slips started slipping at the static limit of its last stick (the break-away level its falling
    branch starts from).
    """

    drive_channel = "vb"
    rig = "belt-ndof"

    def __init__(self, cfg: RigConfig) -> None:
        super().__init__(cfg)
        self.n = cfg.mechanics.n_masses
        self.position_slots = tuple(range(self.n))
        self.velocity_slots = tuple(range(self.n, 2 * self.n))

    def _prepare(self, rec, t, rate, source):
        names = [f"x{i + 1}" for i in range(self.n)]
        for name in names:
            if name not in rec.channels:
                raise InputError(source, name, f"missing column (the rig has {self.n} masses: needs {', '.join(names)})")
        xs = {name: np.asarray(rec.channels[name], dtype=float) for name in names}
        vb = np.asarray(rec.channels["vb"], dtype=float)
        drive_m, drive_c, csrc = self._drive(rec, t, rate, vb, "vb_set")
        sig, src = {}, {}
        for name, x in xs.items():
            sig[name], src[name] = self._sigma(name, x)
        half = 0.006 if rate >= 500 else 1.5 / rate
        xd = {name: sg(x, rate, half, 1) for name, x in xs.items()}
        v_rel = xd["x1"] - drive_m
        m = Measured(self.rig, source, t, rate, xs, {name: "m" for name in names}, sig, src, drive_m, drive_c, csrc,
                     self._temp(rec, rate))
        m.v_rel = v_rel
        m.d_abs_v_rel = sg(np.abs(v_rel), rate, half, 1, degree=2)
        # stuck: within the contact's v_stick of the belt, or within the velocity's own noise where that is larger
        # (seen: 20 um tracker noise at 250 Hz puts 1.7 mm/s on the derivative; with the config's 1 mm/s alone
        # 17 % of the samples read stuck, against 56 % in the simulator's truth; with 4 sigma, 57 %)
        # and never more than a quarter of the drive's speed: the config's 1 mm/s is a belt rig's band at 0.2 m/s;
        # on a spring-slider driven at 1.1 mm/s it read every sample stuck (the slider's 3 mm/s swings included),
        # windows started in stick mode and a perfect model scored 5.6 um on 0.93 um of noise
        band = min(self.cfg.contact.v_stick_m_per_s, 0.25 * float(np.median(np.abs(drive_m))))
        v_stick = max(band, 4.0 * float(noise_sigma(v_rel)))
        m.v_stick = v_stick
        pos = (lambda x: sg(x, rate, half)) if rate >= 500 else (lambda x: x)
        travel = np.concatenate([[0.0], np.cumsum(0.5 * (drive_m[1:] + drive_m[:-1]) / rate)])
        m.context = {"travel": travel}
        for name in names:
            stuck = stuck_by_hysteresis(xd[name] - drive_m, v_stick, 3.0 * v_stick)
            m.context[f"{name}_smooth"] = pos(xs[name])
            m.context[f"{name}_dot"] = np.where(stuck, drive_m, xd[name])
            m.context[f"{name}_stuck_s"] = stuck_time(stuck, rate)
            # the stick that ended last before each sample: how long it lasted (the static limit it broke at)
            m.context[f"{name}_last_stick_s"] = last_stick(m.context[f"{name}_stuck_s"])
        m.context["stick_clock"] = m.context["x1_stuck_s"]
        return m

    def output_channels(self):
        return tuple(f"x{i + 1}" for i in range(self.n))

    def model_step(self):
        """STEPS_PER_PERIOD steps per period of the chain's fastest linear mode (never finer than the config's).
        Why coarser than the simulator's step: the hybrid integrator locates every event (stick, slip, a kink of
        the law) and between events RK4 integrates a smooth oscillator, whose error at 100 steps per period is
        far below any tracker's noise; the rig config's 0.5 ms is the simulator's, chosen so that 2 kHz
        sensors need no sub-steps. At 0.5 ms a 2 kHz record costs 6x the simulation it needs."""
        mech = self.cfg.mechanics
        f_max = float(np.max(beltndof.chain_modes(mech.mass_kg, mech.stiffness_N_per_m, mech.n_masses)))
        return max(self.cfg.integrator.dt_s, 1.0 / (STEPS_PER_PERIOD * f_max))

    def law_guess(self, m):
        """Break-away and kinetic levels of mass 1 from the spring force the data show (an equation-error pass
        without derivatives): at the last stuck sample before each slip the chain holds the static level; over
        the slips it oscillates about the kinetic level. Why: a contact far from the config's law (a user's
        f_s0 = 0.62 against the default 1.33) left the fit at 1061 um against a 2.4 um floor, stuck near the start.
        """
        mech = self.cfg.mechanics
        x = m.context["x1_smooth"]
        need = mech.stiffness_N_per_m * (2.0 * x - m.context["x2_smooth"] if self.n > 1 else x)
        stuck = m.context["x1_stuck_s"] > 0.0
        ends = np.flatnonzero(stuck[:-1] & ~stuck[1:])
        slip = ~stuck
        f0 = mech.normal_force_N
        if ends.size < 2 or slip.sum() < 10:
            return self._law_from_cycles(m, f0) if self.n == 1 else {}
        return {"friction.f_s0": float(np.median(need[ends]) / f0), "friction.f_k0": float(np.mean(need[slip]) / f0)}

    def _law_from_cycles(self, m, f0):
        """Where the data's v_rel cannot tell stick from slip (a spring-slider at 42 um/s: the speed's noise, 50 um/s,
        is above the drive), the load cycles can: the spring holds the static level at each peak, and an inertial
        slip from f_s overshoots the kinetic level as far again, so f_k = f_s - drop k / (2 F0). Without it the
        lab's 42 um/s record kept the config's f_s0 = 1.33 against a load of 0.37 F0: the model never slipped and
        the fit did not move."""
        k = self.cfg.mechanics.stiffness_N_per_m
        cyc = load_cycles(m.t, m.outputs["x1"], m.sigma["x1"])
        if cyc["peak"].size < 3:
            return {}
        f_s = float(np.median(cyc["peak"])) * k / f0
        return {"friction.f_s0": f_s, "friction.f_k0": f_s - float(np.median(cyc["drop"])) * k / (2.0 * f0)}

    def effect_guess(self, m, name, form, v_ref):
        """rate-and-state from the record's own velocity steps and holds, reduced as `daq analyse rsf` does (the
        quasi-static slider, each event on its own window; decision 31): the medians of a, b and Dc by the form's
        law, and the law's level that puts the steady friction where the events found it. Why: from a = b = 0 (or
        the generic a = 0.01) the fit of a velocity-stepping record stayed put or fell into Dc = 0.6 mm, 1.55 um
        against the seed model's 1.31 um; from the reduction's values it reached the floor. A record without steps
        or holds (one constant drive) gives no start."""
        if name != "rate-and-state" or self.n != 1:
            return {}
        mech = self.cfg.mechanics
        t = m.t
        mu = mech.stiffness_N_per_m * np.asarray(m.outputs["x1"]) / mech.normal_force_N
        plats = plateaus(m.drive_command)
        evs = events(t, plats)[:RSF_GUESS_EVENTS]
        if not evs:
            return {}
        rt, rv = programme_table(t, plats)
        travel = load_point_travel(t, rt, rv)
        law = "slip" if form == "slip" else "aging"
        got = []
        for ev in evs:
            sl = slice(ev.i_start, ev.i_end + 1)
            f = fit_law(ev, t[sl], mu[sl], rt, rv, law, start_values(ev, t[sl], mu[sl], travel[sl], None))
            if f.ok:
                got.append((f.a.value, f.b.value, f.Dc_m.value, f.mu0.value - f.a_minus_b.value * math.log(ev.v1 / v_ref)))
        if not got:
            return {}
        a, b, dc, level = (float(np.median(col)) for col in zip(*got))
        return {"effects.rate-and-state.a": a, "effects.rate-and-state.b": b, "effects.rate-and-state.dc": dc,
                "friction.f_k0": level, "friction.f_s0": level}

    def predict(self, sim, states):
        return {f"x{i + 1}": states[..., i] for i in range(self.n)}

    def output_rates(self, sim, states, dt):
        return {f"x{i + 1}": states[..., self.n + i] for i in range(self.n)}

    def start_state(self, sim, m, i):
        c, n = m.context, self.n
        s = np.zeros(beltndof.n_state(n))
        for k in range(n):
            s[k] = c[f"x{k + 1}_smooth"][i]
            s[n + k] = c[f"x{k + 1}_dot"][i]
        tail = 2 * n
        s[tail + TAIL.TEMP] = m.temp[i] if m.temp is not None else self.cfg.contact.t_ambient_C
        s[tail + TAIL.VLAG] = m.drive_measured[i]
        s[tail + TAIL.POS] = c["travel"][i]
        if sim.e[E.RS_DC] > 0.0:
            s[tail + TAIL.PSI] = rsf_state_at(sim, m, i)
        return s

    def before_window(self, sim, m, i, s0):
        c, n = m.context, self.n
        p, e = sim.p, sim.e
        t_rel = float(m.t[i] - m.t[0])
        vb = float(m.drive_measured[i])
        hs = beltndof.new_hybrid(n, p[beltndof.P.F_S0], 1.0)
        rate_need = p[beltndof.P.K] * vb  # paper 000's Delta for a mass on a steady belt: K S
        for k in range(n):
            stuck_s = float(c[f"x{k + 1}_stuck_s"][i])
            if stuck_s > 0.0:
                level = beltndof._static_limit(stuck_s, rate_need, p, e) + beltndof.state_term(s0, 2 * n, e)
                need = self._need_stuck(p, e, s0, k, vb)
                if abs(need) <= p[beltndof.P.F0] * level:
                    hs[beltndof.H.MODE, k] = beltndof.STICK
                    hs[beltndof.H.STICK_T0, k] = t_rel - stuck_s
                    # a stuck mass moves with the belt: its start velocity is no free value (a fit that moved it,
                    # seen at 1e3-4e7 m/s since nothing depended on it, made the contact chatter 3e5 times a window)
                    s0[n + k] = vb
                else:
                    # read stuck, but the springs at the start pull harder than the static limit holds: the mass
                    # broke away within the last samples (its slip speed still below the stick threshold). Started
                    # stuck it would break at once from u = 0, late, and slip too far (seen: a window starting 4 ms
                    # after a break, 21 um on a 1.4 um floor with the true law; the fit moved the start 9 um to
                    # compensate). It starts slipping, from the static level, on the drop, start velocity free.
                    hs[beltndof.H.SLIP_DIR, k] = 1.0 if need > 0.0 else -1.0
                    hs[beltndof.H.FS_BREAK, k] = level
            else:
                w = vb - float(c[f"x{k + 1}_dot"][i])
                hs[beltndof.H.SLIP_DIR, k] = 1.0 if w >= 0.0 else -1.0
                hs[beltndof.H.FS_BREAK, k] = beltndof._static_limit(float(c[f"x{k + 1}_last_stick_s"][i]), rate_need,
                                                                    p, e)
        sim.hybrid = hs

    @staticmethod
    def _need_stuck(p, e, s0, k, vb) -> float:
        """Friction [N] that would hold mass k stuck at the start state s0 on a belt at vb (its inertia on a
        steady belt neglected: a window's start velocity is all the data give)."""
        n = int(p[beltndof.P.N])
        K = p[beltndof.P.K]
        damp = e[E.D_BELT] * math.sqrt(K * p[beltndof.P.M])
        return damp * vb + beltndof.chain_at(s0[:n], k, n, K)
