"""The loss of every fit: Huber's on the noise-scaled residual, in the scale each window's residuals show.

Why a robust loss: single-sample spikes are repaired before anything reads the data (RigData._despike), but a
real file carries what that repair cannot see: bursts of two or three bad samples (each one's neighbours are
bad too), and glitches under its threshold. Under least squares a handful of them outweighs everything else (20
bursts of two 30-level spikes on an 8 s belt record: 40 samples carried 30x the cost of the 1300 good ones, and
the fit chose another basin: f_s0 1.89 for 1.33, decision 26). Huber's loss counts a residual z (model -
measured, in noise levels) as z^2/2 up to a threshold and linearly beyond it, so no sample pulls harder than
the threshold.

Why the threshold scales with each window's own residuals (c x s per window and output, s = max(1, the rms of
its residuals without their largest 5 %), a concurrent scale as Huber's): a fixed threshold of 3 noise levels
takes a model's broad misfit for outliers. With the window's scale, a window the model misses everywhere is
fitted by least squares as before; a window the model follows, s = 1, has its few bad samples capped at 3 noise
levels. Gaussian noise loses < 0.5 % efficiency at c = 3.

Why after least squares and not from the first iteration: from a start far from the data a bounded pull is a
weak one (a misplaced break-away counts linearly), and the fit stalled: decision 25 (soft-L1), and again with
this loss on a glitched slider (k_fall 0.18 for 0.1; least squares' end scores lower under this very loss).
Session runs least squares to convergence, then this loss from there, and only where the residuals hold more
samples beyond the threshold than Gaussian noise puts there (``contaminated``): elsewhere the estimates agree.

How: iteratively reweighted least squares inside our Levenberg-Marquardt (shooting.Problem.fit): each iterate's
weights w = psi(z)/z make the weighted quadratic a majoriser of the loss at that iterate, and a step is accepted
only if the loss itself falls. Pure functions over arrays here; the fits hold the state.
Decision record: docs/decisions/0026-huber-loss-in-the-fit.md.
"""

from __future__ import annotations

import numpy as np

HUBER = "huber"
SQUARES = "squares"
LOSSES = (HUBER, SQUARES)
HUBER_C = 3.0  # threshold in units of the window's residual scale (noise levels on a window the model follows)


TRIM = 0.05  # the scale leaves out this share of a window's largest residuals (outliers are rare, misfit is not)
TRIM_TO_SIGMA = 1.148  # rms of unit Gaussian noise without its largest 5 % is 1 / 1.148


def scale(z: np.ndarray) -> np.ndarray:
    """Per window and output, the residuals' scale in noise levels, never below 1: (..., 1). The rms without the
    largest TRIM of them, so that a few bad samples do not raise it and a misfit over many does."""
    n = z.shape[-1]
    keep = max(1, int(np.ceil((1.0 - TRIM) * n)))
    z2 = np.partition(z * z, keep - 1, axis=-1)[..., :keep]
    return np.maximum(1.0, TRIM_TO_SIGMA * np.sqrt(np.mean(z2, axis=-1, keepdims=True)))


def evaluate(z: np.ndarray, loss: str = HUBER) -> tuple[np.ndarray, np.ndarray]:
    """The loss per window and the IRLS weights per sample of noise-scaled residuals ``z`` (n_win, n_out, n).

    Returns (cost (n_win,), weights like z). Least squares: 0.5 z^2 and weights 1. Huber: 0.5 z^2 where
    |z| <= t, t |z| - 0.5 t^2 beyond, t = HUBER_C x scale(z); weights min(1, t / |z|), so that the weighted
    squares 0.5 w z^2 equal the loss where w = 1 and lie above it elsewhere with the same slope (a majoriser).
    """
    if loss not in LOSSES:
        raise ValueError(f"unknown loss {loss!r}: one of {', '.join(LOSSES)}")
    with np.errstate(over="ignore", invalid="ignore"):  # a trial far off (a diverged window) costs inf, silently
        if loss == SQUARES:
            return 0.5 * np.sum(z * z, axis=(1, 2)), np.ones_like(z)
        a = np.abs(z)
        t = HUBER_C * scale(z)
        inside = a <= t
        rho = np.where(inside, 0.5 * z * z, t * a - 0.5 * t * t)
        w = np.where(inside, 1.0, t / np.maximum(a, 1e-300))
        return np.sum(rho, axis=(1, 2)), w


GAUSS_TAIL = 0.0027  # share of Gaussian noise beyond 3 of its standard deviations (2 (1 - Phi(3)))


def contaminated(z: np.ndarray, loss: str = HUBER) -> bool:
    """Do more samples stand beyond Huber's threshold than Gaussian noise puts there (one-sided, p ~ 0.01)?

    Why ask: where they do not, Huber's estimate is least squares' up to the noise's own tails, and a stage that
    refines it costs iterations for nothing (on the brake benchmark's clean record 0.2 % of samples stood beyond
    the threshold, Gaussian noise puts 0.27 % there, and the stages cost 17 % of the diagnosis)."""
    if loss == SQUARES or z.size == 0:
        return False
    expected = GAUSS_TAIL * z.size
    return float(np.sum(downweighted(z, loss))) > expected + 2.33 * np.sqrt(expected) + 1.0


def counted_linearly(z: np.ndarray, loss: str = HUBER) -> np.ndarray:
    """Which samples the loss counts at less than their square (beyond the threshold): a mask shaped as z."""
    return evaluate(z, loss)[1] < 1.0


def downweighted(z: np.ndarray, loss: str = HUBER) -> np.ndarray:
    """Per output, how many samples the loss counts at less than their square (beyond the threshold)."""
    return np.sum(counted_linearly(z, loss), axis=(0, 2))
