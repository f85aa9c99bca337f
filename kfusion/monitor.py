"""Online consistency monitor: the filter checks its own predictions while the mocap is visible.

Two tests run on the fixes the filter sees anyway (GUIDE §10, "sensor quality"):

* **Windowed NIS.** Over the last N accepted fixes, ``sum NIS_k ~ chi-square(3 N)`` when the
  filter's innovation covariance S is right. :func:`windowed_nis_test` compares the sum with the
  two-sided chi-square interval; the covariance-matching factor is ``mean NIS / 3``
  (:func:`nis_matching_scale`).
* **Shadow gaps.** Every ``shadow_period_s`` a copy of the filter (restored from a snapshot right
  after a fused fix) runs on the IMU alone for ``shadow_window_s``, as if the mocap had been
  occluded. At each fix that follows, the shadow's rigid-body point is compared with the fix,
  ``e = z - p_shadow``, against its covariance ``S = P_p + R`` (the shadow's position
  covariance and the mocap noise): the shadow gap's innovation. R is the configured mocap noise,
  matched down by the windowed NIS when that shows it pessimistic (``R mean NIS / 3`` once the
  window is full and the mean is below 3).

Each shadow row gives two variance scales (:func:`shadow_row_scales`). The innovation scale
(:func:`required_scale`) is the smallest s for which ``s S`` holds e both ways kfusion's bound is
read, inside the confidence-c ellipsoid (``d^2 = e^T S^-1 e <= s F^-1_chi2(3)(c)``) and inside 3
sigma on every axis. If the filter's growth of P in a gap were right, ``d^2 ~ chi-square(3)`` and
s <= 1 at the rate c. The prediction scale, applied to the reported ``P_p``, is the same where it
is at most 1; above 1 it is the smallest s for which ``s P_p + R`` holds e (R is known; scaling
all of S would dilute the excess where R is comparable to ``P_p``: on a simulated arm lift with
an accelerometer scale error far off its datasheet, 3-sigma coverage 0.964 against 0.971). The
bound reads the prediction scales; the refusal rule reads the innovation scales (where R is much
larger than ``P_p`` a prediction scale is ill-determined: a fix's noise a little beyond its
quantile asks for a large multiple of a small P). Scales are kept per horizon bin (time since the
shadow's last fix) over the last ``memory`` rows, and the scale of a bin is covariance matching at
a quantile (:func:`quantile_matching_scale`):

    s(bin) = quantile_q({s_k in bin}),  q = matching_quantile

clipped to ``[minimum_scale, inf)``. A scale below 1 also needs enough rows in its bin for the
quantile to be known (:func:`rows_to_shrink`): the largest of n rows is below the true q-quantile
with probability q^n, so with fewer than ``ln(1/2) / ln(q)`` rows (139 at q = 0.995) even the
largest row more likely than not understates it, and the bin's scale stays at least 1 (measured on
the first 30 s of BROAD trial 21: hold-out bins of 20-60 rows gave smoother scales of 0.12-0.16
and 36 % of its bridged rows beyond the 99 % bound). A real gap's position covariance is reported as
``max(s(bin(h)), s_NIS) P`` at horizon h (beyond the last bin, the last bin's scale), where
``s_NIS = mean NIS / 3`` when the windowed NIS test fails high (else no constraint): the bound
grows as the shadow gaps showed it must, not only as the profile predicts, and shrinks (down to
``minimum_scale``) where the profile is pessimistic. Until ``minimum_shadow_gaps`` gaps have been
seen the scale is at least 1 (the profile).

When the standard-deviation scale needed anywhere exceeds ``max_std_scale`` the monitor refuses
to bridge: outputs in a gap are ``lost``. The IMU model is then not trusted at the fixes either
(the fused posterior is built on its prediction): the Tracker shows, at a fix, that fix alone
with covariance R (:meth:`ConsistencyMonitor.fix_only`), and nothing between fixes. The reported
bound is then never a number the data contradicted.

The IMU clock (:func:`gap_clock_evidence`, :func:`clock_offset_estimate`): a clock offset ``d``
makes a shadow gap drift by about ``d`` times its velocity change. Each gap gives a
least-squares ``d_g``; their weighted mean has a jackknife 1-sigma. It is a diagnostic, not a
test: other model errors correlate with the velocity change too (on simulated circles with no
offset it reads -5 to -8 ms +- 0.4-0.8 ms, where ``check``'s accelerometer timing reads -0.3 +-
0.3 ms), so it only names the cause when the shadow gaps' scale already refused the model and
the offset is beyond ``clock_tolerance_s`` by ``clock_sigmas``. Health reports it. Measured on
60 s simulated recordings, an undeclared 20 ms offset is named on all 4 scenarios.

A fix fused with a prediction the monitor found wrong (:meth:`ConsistencyMonitor.at_fix`): the
posterior ``P+`` assumes the prediction's ``P-``. With the shadow gaps' scale ``s`` for that
prediction's horizon it is ``P+ + (s - 1)(P+ - P+ R^-1 P+)`` (:func:`fix_covariance_under_scale`),
and while the windowed NIS test fails high with factor ``k`` it gains ``(k - 1)(R - P+)``
(:func:`fix_covariance_under_innovation_factor`): a few ms after the last fix ``P-`` is far below
R, so innovations k times too large say the fused position is nearly as uncertain as the fix
itself, not k times its ``P+``.

Rival hypotheses (:meth:`ConsistencyMonitor.cover_rivals`): the gate cannot tell a marker swap
from a broken model. A fix gated since the last fused one may be right, so the bound is widened
to hold it (``P + d d^T + R``); a fix fused after gated ones (a swapped marker passing the gate
once the prediction has grown loose) may be wrong, so the prediction it replaced stays a rival
for ``max_bridge_s`` (``P + d d^T + P_prior``). Below the gate the same holds for a step: a fix
fused with an NIS beyond its quantile at ``step_probability`` (a marker of the cluster dropping
out shifts the solved rigid body by a few mm for as long as it is missing; the filter follows the
shifted fixes within a few frames and its innovations shrink again, while the bound at a fix is
about ``P+``, far below the shift) keeps the prediction it was fused with as a rival for
``max_bridge_s`` (``P + d d^T + S``, d = -y, recovered from the fused point:
:func:`innovation_from_posterior`); when the fixes jump back, that step is a rival too. Measured
on 60 s of simulated random_reach with 31 glitches of 3-4 mm lasting 5-20 frames: 1.8-6.0 % of
the rows beyond the 99 % bound, errors up to 4.1x it, before; 0.5-1.2 % after, where the
remainder is glitches that begin inside an occlusion (the first fix after it is already shifted
and agrees with the loose prediction: no innovation shows them).

Suspected cause (:func:`suspected_cause`): from the shadow errors, fitted as a constant
acceleration error ``e(h) ~ e_0 + v h + a h^2 / 2`` per shadow gap. An error of the order of g
along gravity, the same in every gap, points at gravity (sign, axis or units); a large
acceleration error that changes direction from gap to gap points at the IMU disagreeing with the
mocap motion (clock offset, mount, quaternion order); a moderate scale with a consistent NIS at
fixes points at an IMU noisier than its profile; an inconsistent NIS alone points at mocap noise.
A heuristic, named as such in health: it says where to look, ``kfusion check`` diagnoses.

Offsets on the fixes before an occlusion (:meth:`ConsistencyMonitor.cover_rivals`): a marker
blob partly hidden as the body is lost shifts the solved body for the last few frames, the
filter takes part of the shift in (position ``a d``, velocity ``b d``:
:func:`edge_sensitivity`), and the gap is bridged from it with a bound that knows nothing of it.
The shadow gaps start from clean fixes and cannot show it. Two tests can, each a windowed test
over the last ``gap_end_window`` occlusions:

* the fixes that end real gaps: each gives its NIS and the offset variance it needed
  (:func:`edge_variance_needed`, shape ``(a + b H)^2`` at the gap's length H), against the
  predictions as the shadow gaps scaled them (what those explain is no edge);
* the fixes before each occlusion, tested once it is a real gap (``settle_after_s`` after the
  last fix; a dropped frame is none): an offset d on the last
  ``edge_frames`` of them shows in their innovations with a known signature ``y_j = g_j d +
  w_j`` (:func:`edge_innovation_signature`), and the likelihood ratio ``T = d^T J d^``
  (:func:`edge_offset_evidence`; against S times the NIS window's factor, so that innovations
  too large at every fix are no edge) is chi-square(3), as a fix's NIS, without one. This test
  comes ``settle_after_s`` into the gap, not at its end, so it can cover the rest of the gap
  these fixes lead into, where the first waits for gaps to end; with the body drifting 1.5 mm
  over the 5 frames before each occlusion it fired after 1-2 occlusions, the gap ends' test
  after 2-7. It runs over the last ``edge_s`` of fixes and over each of ``longer_edges_s``
  (an offset on 5 frames hardly shows in the last 3), each span its own windowed test at
  ``edge_test_probability``, looser than the NIS tests' (one value per occlusion fills a
  window slowly, and a miss costs more than a false alarm).

While either fails high (mean beyond the windowed limit), until its mean is back to 3, the bound
h s into a gap adds ``sigma^2 (a + b h)^2`` per axis, sigma^2 the larger of the two tests'
``matching_quantile`` of the variances they kept (the gap starts': ``(|d^|^2 - tr J^-1) / 3``, a
moment estimate), the gap ends' ``mean NIS / 3`` scales the gap's covariance, and each fix's
bound holds an offset of ``min(sigma^2, sigma_step^2)``, and no row of the gap after it less
(:meth:`ConsistencyMonitor.edge_offset_variance`). The first
occlusion is bridged before either test has evidence (a shift the size of the mocap noise per
frame does not show in the fixes' own NIS; a larger one is a step:
:meth:`ConsistencyMonitor._step`). The smoother tests the same offline, by hiding the fixes
before each gap (:func:`kfusion.kalman.smoother.edge_holdout`).

Innovations correlated over fixes (:func:`block_nis`): the windowed NIS test looks at each fix
alone, and errors the model takes as white but that persist over several fixes pass it (an IMU
whose rate drops 8x without anti-aliasing holds each sample's error over four 100 Hz fixes: each
fix's NIS about 3-4, the fused point 0.5-0.6 mm off with a 0.15 mm std). The sum of B =
``block_fixes`` consecutive innovations has covariance ``sum S_k`` only when they are white; its
NIS over the window's blocks is tested like the fixes' own, and from when it fails high until
the mean is back to 3 its ``mean / 3`` is the matching factor
(:meth:`ConsistencyMonitor.at_fix`, the gaps' scale), as for the per-fix test. On the simulated
IMU rate drop the block NIS averaged 9-13 after the drop and 2.2-2.9 before. On the 7 BROAD
trials (whole, with held-out gaps cut) the fixes' NIS is about 0.1 (the configured mocap noise
is pessimistic there); the test fired on trials 21, 24 and 28, 1-3 times each for about 1 s
(window means 6-7: fast motion and taps), and the 47 recordings of
``benchmarks/bound_coverage.py`` kept their coverage (trial 28's kalman bound/error 3.56 ->
3.59, the rest identical).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.conventions import ACCEPTED, GATED, INITIALISED, REACQUIRED, USED_OUTCOMES
from kfusion.guards import short_repr

if TYPE_CHECKING:
    from kfusion.kalman.filter import FilterEstimate, KalmanFusion, KalmanSnapshot, UpdateOutcome

CONSISTENT: Final = "consistent"
GRAVITY: Final = "gravity direction, sign or units"
IMU_MOTION: Final = "IMU disagrees with the mocap motion (clock offset, mount or quaternion order)"
IMU_NOISE: Final = "IMU noisier than its profile"
MOCAP_NOISE: Final = "mocap noisier than configured"
CLOCK: Final = "IMU clock offset against the mocap"
EDGES: Final = "mocap off on the frames before occlusions"
CORRELATED: Final = "prediction errors persist over fixes (IMU slower or noisier than its profile)"
CAUSES: Final = (CONSISTENT, GRAVITY, IMU_MOTION, IMU_NOISE, MOCAP_NOISE, CLOCK, EDGES,
                 CORRELATED)
"""Suspected causes reported in :attr:`MonitorReport.suspected_cause`."""


# ---------------------------------------------------------------------------------------------
# Pure functions
# ---------------------------------------------------------------------------------------------


@lru_cache(maxsize=1024)
def chi2_quantile(probability: float, dof: int) -> float:
    """F^-1 of chi-square with ``dof`` degrees of freedom (scipy, cached: a filling NIS window
    of N fixes asks for 2 N of them, 200 with the default window, every run)."""
    from scipy.stats import chi2

    return float(chi2.ppf(probability, dof))


def normalised_error_squared(error: ArrayLike, covariance: ArrayLike) -> float:
    """``d^2 = e^T P^-1 e`` for an error e (3,) m and covariance P (3, 3) m^2; inf when P is
    singular or not finite. ``P x = e`` is solved by Gaussian elimination with partial
    pivoting (the method of LAPACK's ``gesv``, which :func:`normalised_errors_squared` calls;
    not its bits: the two agree to about 1e-12 relative at condition numbers up to 1e10, 1e-4
    at 1e12, and not at all near singular, where every caller's ``+ R`` keeps S) in Python
    floats: about 5 us, where a LAPACK call from Python costs 15-20 us, and the monitor asks
    for one at every block of fixes and every gap's end."""
    e = np.asarray(error, dtype=float).tolist()
    a = np.asarray(covariance, dtype=float).tolist()
    if not all(map(math.isfinite, e + a[0] + a[1] + a[2])):
        return math.inf
    b = list(e)
    for column in range(3):
        pivot = max(range(column, 3), key=lambda row: abs(a[row][column]))
        if a[pivot][column] == 0.0:
            return math.inf  # singular
        a[column], a[pivot] = a[pivot], a[column]
        b[column], b[pivot] = b[pivot], b[column]
        for row in range(column + 1, 3):
            multiplier = a[row][column] / a[column][column]
            for entry in range(column, 3):
                a[row][entry] -= multiplier * a[column][entry]
            b[row] -= multiplier * b[column]
    x = [0.0, 0.0, 0.0]
    for row in (2, 1, 0):
        x[row] = (b[row] - sum(a[row][entry] * x[entry] for entry in range(row + 1, 3))) \
            / a[row][row]
    value = e[0] * x[0] + e[1] * x[1] + e[2] * x[2]
    return value if math.isfinite(value) else math.inf


def normalised_errors_squared(errors: NDArray[np.float64], covariances: NDArray[np.float64]
                              ) -> NDArray[np.float64]:
    """(k,) ``d^2 = e^T P^-1 e`` of k stacked errors e (k, 3) m with covariances P (k, 3, 3)
    m^2 (solved with LAPACK's pivoted LU, ``np.linalg.solve``); inf where P is singular or
    not finite."""
    result = np.full(len(errors), math.inf)
    finite = np.isfinite(covariances).all(axis=(1, 2)) & np.isfinite(errors).all(axis=1)
    if not finite.any():
        return result
    e, P = errors[finite], covariances[finite]
    try:
        solved = np.linalg.solve(P, e[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:  # a singular one among them: each on its own
        result[finite] = [_solved_or_inf(*pair) for pair in zip(e, P, strict=True)]
        return result
    result[finite] = np.einsum("ki,ki->k", e, solved)
    return result


def _solved_or_inf(error: NDArray[np.float64], covariance: NDArray[np.float64]) -> float:
    """``e^T P^-1 e`` of one finite error (3,) and covariance (3, 3); inf when P is singular."""
    try:
        return float(np.einsum("i,i->", error, np.linalg.solve(covariance, error)))
    except np.linalg.LinAlgError:
        return math.inf


def required_scale(error: ArrayLike, covariance: ArrayLike, confidence: float = 0.99,
                   sigmas: float = 3.0) -> float:
    """Smallest variance scale s for which ``s P`` holds the error e (3,) m both ways kfusion's
    bound is read: inside the ellipsoid of confidence c, ``d^2 <= s F^-1_chi2(3)(c)``, and
    inside ``sigmas`` standard deviations on every axis, ``e_i^2 <= s sigmas^2 P_ii``:

        s = max(d^2 / F^-1_chi2(3)(c), max_i e_i^2 / (sigmas^2 P_ii))

    inf when P is singular or not finite. (:func:`required_scales` for k rows stacked.)"""
    return float(required_scales(np.asarray(error, dtype=float)[None],
                                 np.asarray(covariance, dtype=float)[None], confidence,
                                 sigmas)[0])


def required_scales(errors: NDArray[np.float64], covariances: NDArray[np.float64],
                    confidence: float = 0.99, sigmas: float = 3.0) -> NDArray[np.float64]:
    """(k,) :func:`required_scale` of k stacked errors (k, 3) m and covariances (k, 3, 3)
    m^2."""
    d2 = normalised_errors_squared(errors, covariances)
    variances = np.diagonal(covariances, axis1=1, axis2=2)
    result = np.full(len(errors), math.inf)
    valid = np.isfinite(d2) & (variances > 0).all(axis=1)
    if valid.any():
        e, v = errors[valid], variances[valid]
        per_axis = np.max(e * e / v, axis=1) / (sigmas * sigmas)
        result[valid] = np.maximum(d2[valid] / chi2_quantile(confidence, 3), per_axis)
    return result


def shadow_row_scales(error: ArrayLike, covariance: ArrayLike, noise_variance: ArrayLike,
                      confidence: float = 0.99, sigmas: float = 3.0
                      ) -> tuple[float, float]:
    """(innovation scale, prediction scale) of a shadow-gap row: an innovation e (3,) m = fix -
    prediction, the prediction's covariance P (3, 3) m^2 and the fix's noise ``r I`` (m^2).
    Floats for one row; for k rows stacked (e (k, 3), P (k, 3, 3), r a float or (k,)), two
    (k,) arrays (:func:`shadow_rows_scales`).

    * The innovation scale is ``required_scale(e, P + r I)``: how far the whole innovation
      covariance S was off. It measures how wrong the model is (the refusal rule reads it).
    * The prediction scale is the variance scale the reported covariance ``P`` needs: the
      innovation scale where that is at most 1 (evidence that shrinks the bound is read on the
      whole innovation: a small error cannot tell a good prediction from a fix whose noise
      happened to cancel its error); above 1, the smallest s for which ``s P + r I`` holds e
      both ways the bound is read (``e^T (s P + r I)^-1 e <= F^-1_chi2(3)(c)`` and
      ``e_i^2 <= sigmas^2 (s P_ii + r)``), since the fix's noise is known and is not the part
      that was wrong. Scaling S instead dilutes the excess where r is comparable to P: a
      prediction whose error has twice its covariance, with P = r, needs s = 2 but gives
      ``(2 P + r) / (P + r)`` = 1.5. Where r is much larger than P the prediction scale is
      ill-determined (a fix's noise a little beyond its quantile asks for a large multiple of
      a small P), which is why the refusal rule reads the innovation scale.

    The ellipsoid condition is solved by Newton's method on
    ``g(s) = sum_i u_i^2 / (s lambda_i + r) - F^-1_chi2(3)(c)`` (``P = V diag(lambda) V^T``,
    ``u = V^T e``): g is convex and decreasing, so from a point with ``g > 0`` the iterates
    rise to the root without passing it. inf when P is singular or not finite, or when no
    finite s holds e."""
    innovation, prediction = shadow_rows_scales(
        np.asarray(error, dtype=float)[None], np.asarray(covariance, dtype=float)[None],
        np.asarray(noise_variance, dtype=float).reshape(1), confidence, sigmas)
    return float(innovation[0]), float(prediction[0])


def shadow_rows_scales(errors: NDArray[np.float64], covariances: NDArray[np.float64],
                       noise_variances: ArrayLike, confidence: float = 0.99,
                       sigmas: float = 3.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(innovation scales (k,), prediction scales (k,)) of k shadow-gap rows stacked: errors
    (k, 3) m, the predictions' covariances (k, 3, 3) m^2, the fixes' noise variances r (k,) or
    one float, m^2 (:func:`shadow_row_scales`, whose docstring gives the rule). The monitor
    computes a shadow gap's rows at once when it closes."""
    count = len(errors)
    noise = np.broadcast_to(np.asarray(noise_variances, dtype=float), (count,))
    whole = required_scales(errors, covariances + noise[:, None, None] * np.eye(3), confidence,
                            sigmas)
    prediction = whole.copy()
    for row in np.flatnonzero(np.isfinite(whole) & (whole > 1.0)).tolist():
        prediction[row] = _prediction_scale(errors[row], covariances[row], float(noise[row]),
                                            float(whole[row]), confidence, sigmas)
    return whole, prediction


def _prediction_scale(e: NDArray[np.float64], P: NDArray[np.float64], noise_variance: float,
                      whole: float, confidence: float, sigmas: float) -> float:
    """The prediction scale of one row whose innovation scale ``whole`` exceeds 1: Newton's
    method from ``whole`` on the ellipsoid condition, and the per-axis condition
    (:func:`shadow_row_scales`)."""
    eigenvalues, vectors = np.linalg.eigh(0.5 * (P + P.T))
    u2 = (vectors.T @ e) ** 2
    limit = chi2_quantile(confidence, 3)
    scale = whole  # g(whole) >= 0: s P + r I <= s (P + r I) for s > 1
    for _ in range(100):
        denominators = scale * eigenvalues + noise_variance
        excess = float(np.sum(u2 / denominators)) - limit
        slope = -float(np.sum(u2 * eigenvalues / denominators ** 2))
        if excess <= 0.0:
            break
        if not slope < 0.0:
            return math.inf
        step = -excess / slope
        scale += step
        if step <= 1e-12 * scale:
            break
    per_axis = float(np.max((e * e / (sigmas * sigmas) - noise_variance) / np.diag(P)))
    return max(scale, per_axis)


@dataclass(frozen=True)
class NisTest:
    """Result of :func:`windowed_nis_test`.

    Attributes:
        mean: mean NIS over the window.
        lower, upper: the interval the mean lies in with probability ``probability`` when the
            filter is consistent: ``F^-1_chi2(dof N)((1 -+ probability) / 2) / N``.
        consistent: lower <= mean <= upper (True for an empty window).
        samples: N.
    """

    mean: float
    lower: float
    upper: float
    consistent: bool
    samples: int


def windowed_nis_test(nis: ArrayLike, probability: float = 0.999, dof: int = 3) -> NisTest:
    """Two-sided chi-square test of the mean of N NIS values of ``dof`` each:
    ``N mean ~ chi-square(dof N)`` under a consistent filter."""
    values = np.asarray(nis, dtype=float)
    values = values[np.isfinite(values)]
    n = len(values)
    if n == 0:
        return NisTest(math.nan, 0.0, math.inf, True, 0)
    mean = sum_mean(values.tolist())  # as the monitor's running window
    lower, upper = nis_interval(n, probability, dof)
    return NisTest(mean, lower, upper, lower <= mean <= upper, n)


def sum_mean(values: Sequence[float] | NDArray[np.float64]) -> float:
    """The mean of the non-empty ``values`` from their correctly rounded sum (``math.fsum``), so
    that every window of NIS values gives the same mean however it was formed; numpy's mean
    (inf) where finite values sum beyond the largest float, for which fsum raises."""
    try:
        return math.fsum(values) / len(values)
    except OverflowError:
        with np.errstate(over="ignore"):
            return float(np.mean(np.asarray(values, dtype=float)))


def add_exactly(partials: list[float], value: float) -> bool:
    """Add the finite ``value`` to a sum held exactly as non-overlapping ``partials`` (in
    place), the summation ``math.fsum`` runs (Shewchuk): afterwards ``math.fsum(partials)`` is
    the correctly rounded sum of every value added, so a window's sum kept by adding each new
    value and the negated one leaving gives :func:`sum_mean`'s bits without summing the window
    again. Each step adds ``value`` to the partials from the smallest up::

        hi = x + y,   lo = y - (hi - x)     (|x| >= |y|: hi + lo == x + y exactly)

    keeping the nonzero ``lo`` and carrying ``hi``. Returns False, with ``partials`` no longer
    valid, where a carry overflows (sums beyond the largest float: the caller sums the values
    again)."""
    index = 0
    for partial in partials:
        if abs(value) < abs(partial):
            value, partial = partial, value
        high = value + partial
        if not math.isfinite(high):
            return False
        low = partial - (high - value)
        if low:
            partials[index] = low
            index += 1
        value = high
    partials[index:] = [value]
    return True


@lru_cache(maxsize=1024)
def nis_interval(samples: int, probability: float = 0.999, dof: int = 3) -> tuple[float, float]:
    """(lower, upper): the interval the mean of ``samples`` NIS values of ``dof`` each lies in
    with ``probability`` under a consistent filter,
    ``F^-1_chi2(dof N)((1 -+ probability) / 2) / N`` (:func:`windowed_nis_test`)."""
    tail = 0.5 * (1.0 - probability)
    return (chi2_quantile(tail, dof * samples) / samples,
            chi2_quantile(1.0 - tail, dof * samples) / samples)


def mean_beyond_limit(nis: Sequence[float] | NDArray[np.float64], probability: float = 0.999
                      ) -> bool:
    """True when the mean of N NIS values (3 dof each) is beyond the windowed test's upper limit
    at ``probability`` (:func:`nis_interval`: the innovations larger than their covariance
    says); False for none."""
    samples = len(nis)
    return samples > 0 and sum_mean(nis) > nis_interval(samples, probability)[1]


def failing_high(nis: Sequence[float], probability: float, on: bool) -> bool:
    """A windowed NIS test with hysteresis: True from when the window's mean fails high
    (:func:`mean_beyond_limit`) until it is back to 3, the mean of a consistent filter's NIS
    (``on``: the state before this window; an empty window keeps it). Switching off at the
    limit itself made a window near it flicker on and off."""
    if mean_beyond_limit(nis, probability):
        return True
    if len(nis) and sum_mean(nis) <= 3.0:
        return False
    return on


def step_offset_variance(noise_variance: float, params: MonitorParameters) -> float:
    """Per-axis variance (m^2) of the largest offset a fix can carry below the step rule,
    as an edge-offset sigma^2: a fix offset by d fused with an NIS beyond
    ``F^-1_chi2(3)(step_probability)`` (30.7) is a step (:meth:`ConsistencyMonitor._step`, a
    rival), and ``|d|^2 <= 30.7 S`` below it, with S at least the mocap noise R
    (``noise_variance``, m^2, per axis); the sigma^2 whose 99 % ellipsoid reaches such a d::

        sigma_step^2 = F^-1_chi2(3)(step_probability) R / F^-1_chi2(3)(confidence)

    (2.7 R: 0.49 mm for R = (0.3 mm)^2). It bounds an offset that appears at once. A drift
    whose frame-to-frame steps stay below the rule is followed by the filter and can carry
    more (3 mm over 20 frames: the fixes before the gaps beyond the bound as often as with no
    cover at fixes); those are left to the gaps' cover (open)."""
    return (chi2_quantile(params.step_probability, 3) * noise_variance
            / chi2_quantile(params.confidence, 3))


def block_nis(y_sum: ArrayLike, S_sum: ArrayLike) -> float:
    """NIS of the sum of B consecutive innovations: ``(sum y_k)^T (sum S_k)^-1 (sum y_k)``,
    for the innovations y_k (3,) m of B fixes in a run and their covariances S_k (3, 3) m^2
    summed (``y_sum`` (3,) m, ``S_sum`` (3, 3) m^2); inf when the sum of S is singular.

    A consistent filter's innovations are white, so ``Var(sum y_k) = sum S_k`` and the block
    NIS is chi-square(3): mean 3, like one fix's. Errors the model takes as white but that
    persist over several fixes (an IMU sample held over four fixes when its stream slows
    down, a drift) correlate the innovations: each fix's NIS can stay near 3 while the sum
    grows like B instead of sqrt(B), and the block NIS grows with it (with correlations
    rho_k at lag k, its mean is ``3 (1 + 2 sum_k (1 - k / B) rho_k)``: 4.8 x 3 for AR(1),
    rho = 0.8, B = 8). The fused position averages recent fixes, so it is then worse than P+
    says by about the same factor; :meth:`ConsistencyMonitor.at_fix` widens it by the
    window's ``mean / 3`` as for the per-fix test (scalar check: B = 2, y = (1, 1), S = (1,
    1): 4 / 2 = 2; y = (1, -1): 0)."""
    return normalised_error_squared(y_sum, S_sum)


def nis_matching_scale(nis: ArrayLike, dof: int = 3) -> float:
    """Covariance-matching factor ``mean NIS / dof`` (1 for an empty window): the factor by which
    the innovation covariance is too small (> 1) or too large (< 1)."""
    values = np.asarray(nis, dtype=float)
    values = values[np.isfinite(values)]
    return sum_mean(values.tolist()) / dof if len(values) else 1.0


def quantile_matching_scale(required: ArrayLike, confidence: float = 0.99) -> float:
    """Covariance matching at a quantile: the variance scale ``quantile_c(s_k)`` of the scales
    each error needed (:func:`required_scale`), so that the scaled bound holds the observed
    errors at the rate c. NaN for no samples; inf when more than ``1 - c`` of them are inf.
    The quantile is ``np.quantile``'s default (:func:`linear_quantile`)."""
    values = [value for value in np.asarray(required, dtype=float).tolist()
              if not math.isnan(value)]
    if not values:
        return math.nan
    unbounded = sum(1 for value in values if math.isinf(value))
    if unbounded:
        if unbounded / len(values) > 1.0 - confidence:
            return math.inf
        values = [value for value in values if math.isfinite(value)]
    return linear_quantile(sorted(values), confidence)


def linear_quantile(ordered: Sequence[float], quantile: float) -> float:
    """The ``quantile`` of the sorted, finite, non-empty ``ordered`` by linear interpolation
    between order statistics, ``np.quantile``'s default (Hyndman and Fan's 7th method), to the
    bit: with ``v = (n - 1) q``, ``i = floor(v)``, ``g = v - i`` and ``d = x[i+1] - x[i]``, the
    value ``x[i] + d g`` for ``g < 1/2`` and ``x[i+1] - d (1 - g)`` otherwise (numpy's
    ``_lerp``); ``x[n-1]`` for ``v >= n - 1``. In Python floats: the monitor takes one per
    horizon bin whenever a shadow gap closes, where ``np.quantile``'s overhead (about 50 us a
    call) was a tenth of a monitored run."""
    count = len(ordered)
    virtual = (count - 1) * quantile
    if virtual >= count - 1:
        return float(ordered[-1])
    if virtual < 0:
        return float(ordered[0])
    previous = math.floor(virtual)
    gamma = virtual - previous
    low, high = float(ordered[previous]), float(ordered[previous + 1])
    difference = high - low
    return high - difference * (1 - gamma) if gamma >= 0.5 else low + difference * gamma


def rows_to_shrink(quantile: float) -> int:
    """Rows a bin needs before its matched scale may fall below 1: the smallest n with
    ``1 - quantile^n >= 1/2``, i.e. ``n = ceil(ln(1/2) / ln(quantile))``, so that the largest
    row (the order statistic :func:`quantile_matching_scale` ends up at with few rows) is at
    least the true ``quantile`` with probability 1/2 or more. Below that the evidence cannot
    tell a pessimistic profile from rows that have not yet shown the tail; 1 for
    ``quantile`` 1 (the largest row is the matched scale by definition)."""
    if quantile >= 1.0:
        return 1
    return math.ceil(math.log(0.5) / math.log(quantile))


def fix_covariance_under_scale(covariance: ArrayLike, noise_variance: float, scale: float
                               ) -> NDArray[np.float64]:
    """The covariance (3, 3) m^2 of a fused fix's position when the prediction it was fused with
    was ``scale`` times worse than the filter believed.

    The fix moves the position error to ``e+ = (I - K) e- - K v`` with the filter's gain ``K``.
    If the prediction's error has covariance ``s P-`` instead of ``P-`` (the monitor's scale for
    that prediction's horizon), the fused error has ``(I - K) s P- (I - K)^T + K R K^T``, and
    with ``K = P+ R^-1`` (the position block of the optimal gain, ``R = noise_variance I``) and
    the Joseph form ``P+ = (I - K) P- (I - K)^T + K R K^T``::

        P_fix = P+ + (s - 1) (P+ - P+ R^-1 P+)

    (scalar check: ``P+ = k r`` with ``k = p / (p + r)``; ``(1 - k)^2 s p + k^2 r``). It is ``P+``
    when the fix dominates (``P+ -> R``: the prediction did not matter) and ``s P+`` when the
    prediction does. Only for ``s > 1``: a scale below 1 leaves ``P+`` as it is (the fixes'
    bound is not shrunk on the shadow gaps' evidence). ``P+ - P+ R^-1 P+`` is positive
    semi-definite for the optimal gain (``P+ <= R``); where the reported ``P+`` exceeds R (the
    output point's orientation part, rivals) its negative directions are dropped, so the result
    is never smaller than ``P+``. ``covariance``: ``P+`` (3, 3) m^2."""
    P = np.asarray(covariance, dtype=float)
    if not scale > 1.0:
        return P
    return fix_covariances_widened(P[None], noise_variance, np.array([scale]),
                                   np.ones(1))[0]


def fix_covariances_widened(covariances: NDArray[np.float64], noise_variance: float,
                            scales: NDArray[np.float64], factors: NDArray[np.float64]
                            ) -> NDArray[np.float64]:
    """k fused fixes' covariances P+ (k, 3, 3) m^2 widened by both of the monitor's findings
    (:meth:`ConsistencyMonitor.at_fix`): the shadow gaps' ``scales`` (k,) of the predictions
    (:func:`fix_covariance_under_scale`) and the innovations' ``factors`` (k,)
    (:func:`fix_covariance_under_innovation_factor`), each applied where above 1::

        P_fix = P+ + (s - 1) [P+ - P+ R^-1 P+]_+ + (k - 1) [R - P+]_+

    (``[.]_+``: :func:`positive_part` of the symmetric part, ``R = noise_variance I``). Element
    by element (the 3x3 product written out, no BLAS call), so each row has the same bits
    whether computed alone, as the Tracker does at a fix, or stacked, as the batch filter does
    for a recording's fixes at once. inf rows where a scale or factor is infinite."""
    P = np.asarray(covariances, dtype=float)
    scales = np.asarray(scales, dtype=float)
    factors = np.asarray(factors, dtype=float)
    widened = P.copy()
    scaled = (scales > 1.0) & (scales < math.inf)
    if scaled.any():
        Q = P[scaled]
        product = (Q[:, :, 0, None] * Q[:, None, 0, :] + Q[:, :, 1, None] * Q[:, None, 1, :]) \
            + Q[:, :, 2, None] * Q[:, None, 2, :]  # P+ P+, the 3x3 product written out
        correction = Q - product / noise_variance
        widened[scaled] += (scales[scaled] - 1.0)[:, None, None] * positive_parts(
            0.5 * (correction + correction.transpose(0, 2, 1)))
    factored = (factors > 1.0) & (factors < math.inf)
    if factored.any():
        Q = P[factored]
        excess = noise_variance * np.eye(3) - 0.5 * (Q + Q.transpose(0, 2, 1))
        widened[factored] += (factors[factored] - 1.0)[:, None, None] * positive_parts(excess)
    widened[(scales == math.inf) | (factors == math.inf)] = math.inf
    return widened


def positive_part(matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    """The symmetric (3, 3) ``matrix`` with its negative eigenvalues set to 0,
    ``V max(Lambda, 0) V^T``; the matrix itself when it has none (the eigendecomposition is
    skipped when :func:`clearly_positive_definite` shows that)."""
    return positive_parts(np.asarray(matrix, dtype=float)[None])[0]


def positive_parts(matrices: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`positive_part` of each of k symmetric matrices (k, 3, 3): those
    :func:`clearly_positive_definite` shows positive definite as they are, the others through
    their eigendecomposition one by one."""
    clear = clearly_positive_definite_rows(matrices)
    if clear.all():
        return matrices
    result = matrices.copy()
    for row in np.flatnonzero(~clear).tolist():
        values, vectors = np.linalg.eigh(matrices[row])
        if values.min() < 0.0:
            result[row] = (vectors * np.maximum(values, 0.0)) @ vectors.T
    return result


def clearly_positive_definite(matrix: NDArray[np.float64], margin: float = 1e-8) -> bool:
    """True when every eigenvalue of the symmetric (3, 3) ``matrix`` exceeds ``margin`` times
    its largest entry (magnitude) by Gershgorin's circle theorem: each row's diagonal exceeds
    the sum of its off-diagonal magnitudes by that much,

        lambda_min >= min_i (A_ii - sum_{j != i} |A_ij|) > margin max |A_ij|.

    An eigensolver's error is of the order of the machine epsilon (1e-16) times the matrix's
    norm, far below that margin, so ``np.linalg.eigh`` then finds no negative eigenvalue: a
    caller that only clips negative ones may skip it. False otherwise (including NaN)."""
    return bool(clearly_positive_definite_rows(np.asarray(matrix, dtype=float)[None],
                                               margin)[0])


def clearly_positive_definite_rows(matrices: NDArray[np.float64], margin: float = 1e-8
                                   ) -> NDArray[np.bool_]:
    """(k,) :func:`clearly_positive_definite` of k matrices (k, 3, 3), element by element."""
    diagonal = np.diagonal(matrices, axis1=1, axis2=2)
    absolute = np.abs(matrices)
    largest = absolute.reshape(len(matrices), 9).max(axis=1)
    lowest = np.minimum(np.minimum(diagonal[:, 0] - absolute[:, 0, 1] - absolute[:, 0, 2],
                                   diagonal[:, 1] - absolute[:, 1, 0] - absolute[:, 1, 2]),
                        diagonal[:, 2] - absolute[:, 2, 0] - absolute[:, 2, 1])
    with np.errstate(invalid="ignore"):  # NaN or inf entries: not clearly anything
        return np.isfinite(matrices).all(axis=(1, 2)) & (lowest > margin * largest)


def _constant_velocity_model(accelerometer_noise_density: float, period_s: float
                              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(F, Q) of a per-axis constant-velocity model over one fix period T (s), driven by the
    accelerometer's white noise q = density^2 (m^2/s^3):
    ``F = [[1, T], [0, 1]]``, ``Q = q [[T^3/3, T^2/2], [T^2/2, T]]``."""
    T = period_s
    q = accelerometer_noise_density ** 2
    return (np.array([[1.0, T], [0.0, 1.0]]),
            q * np.array([[T ** 3 / 3, T ** 2 / 2], [T ** 2 / 2, T]]))


@lru_cache(maxsize=64)
def edge_sensitivity(accelerometer_noise_density: float, mocap_noise: float, period_s: float,
                     frames: int) -> tuple[float, float]:
    """(a, b): how much of an offset d (m) on the last ``frames`` fixes before a gap the filter
    carries into the gap, per axis, as position ``a d`` (m) and velocity ``b d`` (m/s), so
    that h s into the gap the estimate is off by ``(a + b h) d``.

    A per-axis constant-velocity filter in its steady state stands for the fused one: state
    (p, v), a fix every ``period_s`` s with noise ``r = mocap_noise^2`` (m^2), H = [1, 0],
    F and Q of :func:`_constant_velocity_model`. The steady-state gain K (2,) comes from
    iterating the Riccati recursion; an offset d on each of the last n fixes moves the state by
    ``s_n d`` with

        s_1 = K,  s_{j+1} = (I - K H) F s_j + K.

    Returns s_n = (a, b) (a dimensionless, b in 1/s)."""
    gain, _ = _steady_state(accelerometer_noise_density, mocap_noise, period_s)
    F, _ = _constant_velocity_model(accelerometer_noise_density, period_s)
    closed_loop = (np.eye(2) - np.outer(gain, [1.0, 0.0])) @ F
    sensitivity = gain.copy()
    for _ in range(frames - 1):
        sensitivity = closed_loop @ sensitivity + gain
    return float(sensitivity[0]), float(sensitivity[1])


def _steady_state(accelerometer_noise_density: float, mocap_noise: float, period_s: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(K (2,), P+ (2, 2)): the steady-state gain and posterior covariance of the per-axis
    constant-velocity filter of :func:`edge_sensitivity`, by iterating
    ``P- = F P+ F^T + Q``, ``K = P- H^T / (H P- H^T + r)``, ``P+ = P- - K H P-``."""
    F, Q = _constant_velocity_model(accelerometer_noise_density, period_s)
    r = mocap_noise ** 2
    P = np.diag([r, 1.0])
    gain = np.zeros(2)
    for _ in range(2000):
        prior = F @ P @ F.T + Q
        gain = prior[:, 0] / (prior[0, 0] + r)
        updated = prior - np.outer(gain, prior[0, :])
        if np.allclose(updated, P, rtol=1e-12, atol=0.0):
            return gain, updated
        P = updated
    return gain, P


@lru_cache(maxsize=64)
def smoothed_edge_sensitivity(accelerometer_noise_density: float, mocap_noise: float,
                              period_s: float, frames: int, rows: int = 60
                              ) -> tuple[float, ...]:
    """Position offset (per unit offset d on the last ``frames`` fixes before a gap) of the
    smoothed rows at 0, 1, ..., rows - 1 fixes before the gap's first row, for the steady-state
    filter of :func:`edge_sensitivity` followed by an RTS pass that has no fix after them
    (the gap's far side is as far as the smoother reaches: the rows before the gap lean on the
    offset fixes through it). The filter is linear, so running it on the offsets alone (no
    noise, zero start) gives the sensitivity:

        x_i = (I - K H) F x_{i-1} + K u_i,   u_i = 1 on the last ``frames`` rows, else 0;
        x^s_i = x_i + C (x^s_{i+1} - F x_i),  C = P+ F^T (P-)^-1.

    Returns (rows,) values, nearest the gap first."""
    gain, posterior = _steady_state(accelerometer_noise_density, mocap_noise, period_s)
    F, Q = _constant_velocity_model(accelerometer_noise_density, period_s)
    closed_loop = (np.eye(2) - np.outer(gain, [1.0, 0.0])) @ F
    offsets = np.zeros(rows)
    offsets[rows - frames:] = 1.0
    filtered = np.zeros((rows, 2))
    state = np.zeros(2)
    for row in range(rows):
        state = closed_loop @ state + gain * offsets[row]
        filtered[row] = state
    smoother_gain = posterior @ F.T @ np.linalg.inv(F @ posterior @ F.T + Q)
    smoothed = filtered.copy()
    for row in range(rows - 2, -1, -1):
        smoothed[row] = filtered[row] + smoother_gain @ (smoothed[row + 1] - F @ filtered[row])
    return tuple(float(value) for value in smoothed[::-1, 0])


@lru_cache(maxsize=64)
def edge_innovation_signature(accelerometer_noise_density: float, mocap_noise: float,
                              period_s: float, frames: int) -> tuple[float, ...]:
    """Innovation of each of the last ``frames`` fixes before a gap per unit offset d on all of
    them (the offset of :func:`edge_sensitivity`), for the steady-state filter there, oldest
    first: the filter's state moves by ``s_j d`` after the j-th offset fix (``s_0 = 0``,
    ``s_j = (I - K H) F s_{j-1} + K``), so the j-th fix's innovation carries

        g_j d,  g_j = 1 - H F s_{j-1}

    (g_1 = 1: the first offset fix is all offset; the later ones less, as the filter follows).
    Per axis, dimensionless."""
    gain, _ = _steady_state(accelerometer_noise_density, mocap_noise, period_s)
    F, _ = _constant_velocity_model(accelerometer_noise_density, period_s)
    closed_loop = (np.eye(2) - np.outer(gain, [1.0, 0.0])) @ F
    state = np.zeros(2)
    signature = []
    for _ in range(frames):
        signature.append(1.0 - float((F @ state)[0]))
        state = closed_loop @ state + gain
    return tuple(signature)


def edge_offset_evidence(innovations: Sequence[NDArray[np.float64]],
                         covariances: Sequence[NDArray[np.float64]],
                         signature: Sequence[float]
                         ) -> tuple[float, NDArray[np.float64], NDArray[np.float64]] | None:
    """The generalised likelihood ratio test of an offset d (3,) m on the last n fixes before a
    gap, from their innovations y_j (3,) m and covariances S_j (3, 3) m^2 (oldest first) and the
    offset's signature g_j (:func:`edge_innovation_signature`): with the offset
    ``y_j = g_j d + w_j``, w_j white with covariance S_j, so

        J = sum_j g_j^2 S_j^-1,   d^ = J^-1 sum_j g_j S_j^-1 y_j,   Cov(d^) = J^-1,
        T = d^T J d^ ~ chi-square(3) when there is no offset (mean 3, as a fix's NIS).

    Returns (T, d^ (3,) m, J^-1 (3, 3) m^2); None when an input is not finite or J is
    singular. (Scalar check: one fix, g = 1, S = 1, y = 2: J = 1, d^ = 2, T = 4.)"""
    if len(signature) != len(innovations) or len(signature) != len(covariances):
        raise ValueError(f"edge_offset_evidence: expected as many innovations, covariances "
                         f"and signature values, got {len(innovations)}, {len(covariances)} and "
                         f"{len(signature)}")
    g = np.asarray(signature, dtype=float)
    y = np.asarray(innovations, dtype=float).reshape(len(g), 3)
    S = np.asarray(covariances, dtype=float).reshape(len(g), 3, 3)
    if not (np.isfinite(y).all() and np.isfinite(S).all()):
        return None
    try:  # all k inverses in one call
        inverses = np.linalg.inv(0.5 * (S + S.transpose(0, 2, 1)))
        information = np.einsum("k,kij->ij", g * g, inverses)  # J
        weighted = np.einsum("k,kij,kj->i", g, inverses, y)  # sum_j g_j S_j^-1 y_j
        covariance = np.asarray(np.linalg.inv(information), dtype=np.float64)
    except np.linalg.LinAlgError:
        return None
    if not np.isfinite(covariance).all():
        return None
    offset = covariance @ weighted
    return float(offset @ weighted), offset, covariance


def edge_frames(edge_s: float, period_s: float) -> int:
    """Fixes within ``edge_s`` s before an occlusion at one every ``period_s`` s (at least 1):
    ``max(1, round(edge_s / period_s))``."""
    return max(1, round(edge_s / period_s))


def fixes_before_gaps(t: ArrayLike, fixed: ArrayLike, shortest_gap_s: float
                      ) -> tuple[NDArray[np.int64], float]:
    """For each row with a fix (``fixed`` (m,) bool, times ``t`` (m,) s), how many fixes lie
    between it and the next gap (0: the last fix before it), -1 at rows without a fix and
    after the last gap; a gap: the next fix comes at least ``shortest_gap_s`` s (and 1.5
    periods) after the last (:func:`reacquired_after_gap`). Also returns the fixes' period, s
    (the median spacing of consecutive fixes; NaN with fewer than 2 fixes)."""
    times = np.asarray(t, dtype=float)
    used = np.asarray(fixed, dtype=bool)
    count = np.full(len(times), -1, dtype=np.int64)
    rows = np.flatnonzero(used)
    if len(rows) < 2:
        return count, math.nan
    spacing = np.diff(times[rows])
    period = float(np.median(spacing))
    # rows[end]: the last fix before a gap (and a gap is more than a frame late: at 20 Hz every
    # spacing is settle_after_s)
    ends = np.flatnonzero(spacing >= max(shortest_gap_s, 1.5 * period))
    position = np.searchsorted(ends, np.arange(len(rows)), side="left")
    inside = position < len(ends)
    count[rows[inside]] = ends[position[inside]] - np.arange(len(rows))[inside]
    return count, period


def edge_variance_needed(error: ArrayLike, covariance: ArrayLike, shape: float,
                         confidence: float = 0.99) -> float:
    """The smallest variance ``sigma^2 >= 0`` (m^2 per axis of an edge offset) for which a
    gap's end error e (3,) m lies inside the confidence-c ellipsoid of ``S + sigma^2 c I``:

        e^T (S + sigma^2 c I)^-1 e <= F^-1_chi2(3)(c),

    with S (3, 3) m^2 the innovation covariance at the fix ending the gap (prediction and fix
    noise) and ``c = shape = (a + b H)^2`` (:func:`edge_sensitivity` at the gap's length H).
    The left side falls as sigma^2 grows (``sum_i (u_i^T e)^2 / (lambda_i + sigma^2 c)`` over
    S's eigenpairs), so the root is found by bisection. 0 when e is already inside; inf when
    S or e is not finite or the shape is not positive."""
    e = np.asarray(error, dtype=float)
    S = np.asarray(covariance, dtype=float)
    if not (np.isfinite(e).all() and np.isfinite(S).all()) or not shape > 0:
        return math.inf
    eigenvalues, vectors = np.linalg.eigh(0.5 * (S + S.T))
    if eigenvalues[0] <= 0:
        return math.inf
    projected = ((vectors.T @ e) ** 2).tolist()
    values = eigenvalues.tolist()
    limit = chi2_quantile(confidence, 3)

    def distance(variance: float) -> float:  # floats: 60 bisection steps in about 50 us
        return sum(part / (value + variance * shape)
                   for part, value in zip(projected, values, strict=True))

    if distance(0.0) <= limit:
        return 0.0
    low, high = 0.0, sum(projected) / (limit * shape)  # distance(high) <= limit
    for _ in range(60):
        middle = 0.5 * (low + high)
        if distance(middle) > limit:
            low = middle
        else:
            high = middle
    return high


def reacquired_after_gap(time_since_fix: float, shortest_gap_s: float) -> bool:
    """True when a fix ends a gap: the previous fused fix is at least ``shortest_gap_s`` (s)
    older (``time_since_fix``, s; inf before the first fix, which ends no gap)."""
    return math.isfinite(time_since_fix) and time_since_fix >= shortest_gap_s


def gap_clock_evidence(horizons_s: ArrayLike, errors: ArrayLike, velocity_changes: ArrayLike
                       ) -> tuple[float, float] | None:
    """One shadow gap's evidence of an IMU clock offset: ``(sum r.e, sum r.r)`` over its rows.

    A sample that describes time ``t + d`` but is fused at ``t`` (an IMU clock ``d`` s behind
    the mocap) integrates ``a(t + d) ~ a(t) + d a'(t)``, so over a gap started at a fix the
    shadow's position drifts from the truth by about

        p_shadow(h) - p(h) = c + b h + d (v(h) - v(0)),

    ``c`` and ``b`` the start's position and velocity errors. With the fix as the truth the
    error ``e = fix - shadow`` is ``-(c + b h) - d r``, ``r = v_shadow(h) - v_shadow(0)`` the
    shadow's velocity change (3,) m/s: per axis, ``e`` and ``r`` are projected off ``[1, h]``
    (the start's unknown position and velocity error, and any acceleration at the start) and
    regressed on each other, so ``d = -sum r.e / sum r.r``. None with fewer than 4 rows.

    Args: horizons (k,) s since the gap's fix; errors (k, 3) m, fix minus shadow position;
    velocity_changes (k, 3) m/s."""
    h = np.asarray(horizons_s, dtype=float)
    e = np.asarray(errors, dtype=float).reshape(-1, 3)
    r = np.asarray(velocity_changes, dtype=float).reshape(-1, 3)
    if len(h) < 4 or not (np.isfinite(e).all() and np.isfinite(r).all()):
        return None
    basis = np.column_stack([np.ones_like(h), h])
    e_off = e - basis @ np.linalg.lstsq(basis, e, rcond=None)[0]
    r_off = r - basis @ np.linalg.lstsq(basis, r, rcond=None)[0]
    return float(np.sum(r_off * e_off)), float(np.sum(r_off * r_off))


def clock_offset_estimate(evidence: Sequence[tuple[float, float]]
                          ) -> tuple[float, float] | None:
    """The IMU clock offset ``d`` s (positive: the IMU clock behind the mocap) and its 1-sigma
    from several gaps' :func:`gap_clock_evidence`: ``d = -sum(sum r.e) / sum(sum r.r)``, the
    weighted mean of the gaps' own estimates ``d_g = -(sum r.e)_g / w_g``, ``w_g = (sum
    r.r)_g``. Its 1-sigma is the jackknife's, from the estimates without each gap in turn,

        d_(-g) = -(sum r.e - (sum r.e)_g) / (sum w - w_g),
        var = (G - 1) / G sum (d_(-g) - mean d_(-))^2,

    which holds when the weights are not the gaps' true precisions (within a gap the errors
    are a random walk, not independent rows) and when one gap of violent motion carries most
    of the weight: on BROAD 24 (tapping; its accelerometer timing is within 1 ms) a weighted
    scatter gave +7.0 +- 1.1 ms at the end and a sandwich estimate -12.5 +- 2.2 ms after 52
    gaps, both false alarms. None with fewer than 3 gaps or no motion."""
    pairs = [(numerator, denominator) for numerator, denominator in evidence if denominator > 0]
    if len(pairs) < 3:
        return None
    numerators = np.array([pair[0] for pair in pairs])
    weights = np.array([pair[1] for pair in pairs])
    total = float(weights.sum())
    if not total > 0:
        return None
    offset = -float(numerators.sum()) / total
    remaining = total - weights
    if not (remaining > 0).all():
        return None
    left_out = -(float(numerators.sum()) - numerators) / remaining
    gaps = len(pairs)
    variance = (gaps - 1) / gaps * float(np.sum((left_out - left_out.mean()) ** 2))
    return offset, math.sqrt(variance)


def fix_covariance_under_innovation_factor(covariance: ArrayLike, noise_variance: float,
                                          factor: float) -> NDArray[np.float64]:
    """The covariance (3, 3) m^2 of a fused fix's position when the innovations are ``factor``
    times larger than the filter's S = P- + R says (the windowed NIS test failed high: ``factor
    = mean NIS / 3``), with R right and the excess in the prediction: ``P-_true = k S - R``.

    With the filter's gain, ``e+ = (I - K) e- - K v`` and ``I - K = R S^-1``, so the fused error
    has ``P+ + (k - 1) (I - K) S (I - K)^T = P+ + (k - 1) R S^-1 R``, and ``R S^-1 R = R - P+``
    (``P+ = R S^-1 P- = R - R S^-1 R``)::

        P_fix = P+ + (k - 1) (R - P+)

    (scalar check: ``p = r``, ``k = 2``: ``P+ = r / 2``, the prediction's error ``2 (2 r) - r =
    3 r``, fused with weights 1/2: ``(3 r + r) / 4 = r``; the formula: ``r / 2 + r / 2 = r``). At a
    fix a few ms after the last one ``P-`` is far below R, so a failing NIS means the fused
    position is nearly as uncertain as the fix itself (``(k - 1) R``), not ``k P+``. Only for
    ``k > 1``; ``R - P+`` is clipped to its positive directions (a reported P+ beyond R: the
    output point's orientation part, rivals). ``covariance``: ``P+`` (3, 3) m^2."""
    P = np.asarray(covariance, dtype=float)
    if not factor > 1.0:
        return P
    return fix_covariances_widened(P[None], noise_variance, np.ones(1),
                                   np.array([factor]))[0]


def innovation_from_posterior(fix: ArrayLike, position: ArrayLike, covariance: ArrayLike,
                               noise_variance: float, largest_gain: float = 0.9
                               ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """(y, S): the innovation ``y = z - H x- - c`` (3,) m of a fix z (3,) m that a Kalman
    update with R = r I (``noise_variance`` r, m^2) fused, and its covariance S (3, 3) m^2,
    from after the update: the fused point ``position = H x+ + c`` (3,) m and its covariance
    ``covariance = H P+ H^T`` (3, 3) m^2.

    The gain of that update is ``K = P+ H^T R^-1`` (the optimal gain's identity), so
    ``z - H x+ - c = y - H K y = (R - H P+ H^T) R^-1 y`` and::

        y = R (R - P+)^-1 (z - p+)

    (scalar check: ``p- = r``: ``P+ = r / 2``, the fused point halfway, ``z - p+ = y / 2``; the
    formula: ``r / (r / 2) * y / 2 = y``). The prediction the fix was fused with is then
    ``z - y``, and the innovation's covariance (3, 3) m^2 ``S = H P- H^T + R = R (R - P+)^-1
    R`` (from ``P+ = R S^-1 (S - R)``: ``S^-1 = R^-1 (R - P+) R^-1``). None when the
    gain's largest eigenvalue (that of ``P+ R^-1``) exceeds ``largest_gain``: ``(R - P+)^-1``
    then amplifies whatever the reported point does not share with the update (the output
    map's orientation, corrected by the same frame) by more than ``1 / (1 - largest_gain)``,
    and the prediction was loose anyway (``P- > 9 R`` at 0.9), or when anything is not
    finite."""
    z = np.asarray(fix, dtype=float)
    posterior = np.asarray(covariance, dtype=float)
    margin = noise_variance * np.eye(3) - 0.5 * (posterior + posterior.T)
    if not (math.isfinite(noise_variance) and noise_variance > 0 and np.isfinite(z).all()
            and np.isfinite(position).all() and np.isfinite(margin).all()):
        return None
    if not np.linalg.eigvalsh(margin).min() >= (1.0 - largest_gain) * noise_variance:
        return None
    inverse = np.linalg.inv(margin)
    innovation = noise_variance * (inverse @ (z - np.asarray(position, dtype=float)))
    covariance_of_innovation = noise_variance ** 2 * 0.5 * (inverse + inverse.T)
    return innovation, covariance_of_innovation


def scale_beyond_evidence(scale: ArrayLike, horizon_s: ArrayLike, edges_s: tuple[float, ...]
                          ) -> NDArray[np.float64]:
    """A bin's variance scale where it is used: beyond the last edge (a gap longer than any
    gap the scale was matched on) at least 1. The evidence may shrink the profile's bound only
    where it was measured; beyond it the last bin's scale is an extrapolation. (It does not
    make long gaps honest by itself: on a simulated arm lift with unmodelled sensor errors and
    0.5-1 s gaps, 6.8 % of the kalman rows more than 0.3 s into a gap are beyond the 99 %
    bound with a last-bin scale above 1 already.) ``scale`` and ``horizon_s`` broadcast
    together (s)."""
    scale = np.asarray(scale, dtype=float)
    return np.where(np.asarray(horizon_s) > edges_s[-1], np.maximum(scale, 1.0), scale)


def horizon_bin(horizon_s: float, edges_s: tuple[float, ...]) -> int:
    """Index of the bin holding ``horizon_s``: bin i is ``(edges[i-1], edges[i]]`` (bin 0 from 0);
    horizons beyond the last edge fall in the last bin."""
    for index, edge in enumerate(edges_s):
        if horizon_s <= edge:
            return index
    return len(edges_s) - 1


def horizon_bins(horizons_s: ArrayLike, edges_s: tuple[float, ...]) -> NDArray[np.intp]:
    """:func:`horizon_bin` of each horizon (s), vectorised."""
    return np.minimum(np.searchsorted(np.asarray(edges_s), np.asarray(horizons_s, dtype=float),
                                      side="left"), len(edges_s) - 1)


def fit_acceleration_error(horizon_s: ArrayLike, error: ArrayLike) -> NDArray[np.float64]:
    """Least-squares ``a`` (3,) m/s^2 of ``e(h) = e_0 + v h + a h^2 / 2`` over one shadow gap's
    rows (horizon (k,) s, error (k, 3) m); NaN with fewer than 4 rows."""
    h = np.asarray(horizon_s, dtype=float)
    e = np.asarray(error, dtype=float)
    if len(h) < 4:
        return np.full(3, np.nan)
    design = np.column_stack([np.ones_like(h), h, 0.5 * h * h])
    solution, *_ = np.linalg.lstsq(design, e, rcond=None)
    return np.asarray(solution[2], dtype=float)


def suspected_cause(std_scale: float, nis_consistent: bool, nis_scale: float,
                    accelerations: ArrayLike, gravity: ArrayLike,
                    params: MonitorParameters) -> str:
    """Name the most likely broken assumption (a heuristic; module docstring).

    Args:
        std_scale: largest standard-deviation scale the shadow gaps needed.
        nis_consistent, nis_scale: the windowed NIS test and its matching factor.
        accelerations: (k, 3) acceleration errors fitted to the last shadow gaps, m/s^2.
        gravity: (3,) m/s^2, global frame.
        params: thresholds.
    """
    a = np.asarray(accelerations, dtype=float).reshape(-1, 3)
    a = a[np.isfinite(a).all(axis=1)]
    if std_scale > params.cause_std_scale and len(a):
        mean = a.mean(axis=0)
        g = np.asarray(gravity, dtype=float)
        along = abs(float(mean @ g)) / max(float(np.linalg.norm(g)), 1e-12)
        typical = float(np.sqrt(np.mean(np.sum(a * a, axis=1))))
        if along > params.gravity_error_fraction * float(np.linalg.norm(g)):
            return GRAVITY
        if typical > params.motion_error_acceleration:
            return IMU_MOTION
        return IMU_NOISE
    if std_scale > params.cause_std_scale:
        return IMU_NOISE
    if not nis_consistent and nis_scale > 1.0:
        return MOCAP_NOISE
    return CONSISTENT


def bridging_allowed(std_scale: float, shadow_gaps: int, params: MonitorParameters) -> bool:
    """The refusal rule: bridge only while ``std_scale <= max_std_scale``, and, before
    ``minimum_shadow_gaps`` shadow gaps, only while ``std_scale <= early_max_std_scale``."""
    limit = (params.max_std_scale if shadow_gaps >= params.minimum_shadow_gaps
             else params.early_max_std_scale)
    return std_scale <= limit


# ---------------------------------------------------------------------------------------------
# Parameters, report, state
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MonitorParameters:
    """Settings of the consistency monitor.

    Attributes:
        nis_window: accepted fixes in the windowed NIS test.
        nis_probability: two-sided probability of the NIS interval.
        shadow_window_s: length of a shadow gap, s.
        shadow_period_s: a shadow gap starts at the first fused fix this long after the previous
            one started, s (>= shadow_window_s; the cost is about window/period of a filter).
        horizon_edges_s: upper edges of the horizon bins, s, increasing.
        holdout_edges_s: the same for the smoother's hold-out gaps (distance to the nearest
            fix; the smoother's error varies faster with it than the filter's).
        memory: shadow-gap rows remembered per bin (about 5-10 per gap and bin at 100 Hz:
            2000 rows are the last 200-400 gaps, 2-4 minutes). Long enough that the evidence
            spans the recording's fast and slow parts (with 400, a gap in fast motion after a
            quiet spell got the quiet spell's scale: BROAD kalman coverage 0.965-0.973 on the
            fast trials, 0.971-0.982 with 2000); a model that gets worse still shows within
            ``(1 - matching_quantile) memory`` = 10 rows, one or two shadow gaps.
        confidence: the bound the scale is matched at (chi-square quantile of the radius).
        matching_quantile: quantile of the rows' required scales that the scale matches: a
            little above ``confidence``, since the next gap is not one of the shadow gaps.
        minimum_shadow_gaps: gaps needed before the scale may fall below 1.
        minimum_scale: smallest variance scale (the profile may be pessimistic, but only so far).
        max_std_scale: beyond this standard-deviation scale the monitor refuses to bridge. A
            model that needs more than twice its bound is broken, not merely noisy, and a
            scaled bound does not cover a systematic error: measured with the monitor's final
            scale, every BROAD trial needs at most 1.5 and simulated recordings with
            unmodelled sensor errors at most 1.4, while an undeclared IMU clock offset of 10 ms
            needs 2.2-2.8 and of 20 ms 4.0-5.4 (with 5.0, 20 ms was bridged with 5.8 % of
            the Tracker's rows beyond the 99 % bound, up to 4.9x).
        clock_gaps: shadow gaps whose clock evidence is kept (:func:`gap_clock_evidence`).
        clock_tolerance_s: once the shadow gaps' scale refused the model, an IMU clock offset
            they show beyond this, by more than ``clock_sigmas`` of its 1-sigma, is named as the
            suspected cause (module docstring: the shadow-gap timing is a diagnostic).
        clock_sigmas: see ``clock_tolerance_s``.
        holdout_max_std_scale: the same for the smoother's hold-out. Its scale is matched on
            the recording's own gaps, offline, at their own lengths (nothing is extrapolated
            to gaps still to come), and the smoothed P is small enough that real recordings
            legitimately need more: BROAD 24 (tapping) needed between 2 and 5 and was covered
            at 0.986 with it while the filter took its knocks for smooth motion (with the
            impact rule, :func:`kfusion.kalman.model.interpolation_variance`, 1.2).
        settle_s: when the predictions are shown wrong now -- the sum of the last
            ``recent_fixes`` fixes' NIS beyond its chi-square quantile at ``nis_probability``,
            or a fix ending a gap of at least ``settle_after_s`` with an NIS beyond the
            ``confidence`` quantile (11.3 at 0.99) -- the fused fixes for this long (s) are
            given at least their innovations' factor (mean NIS / 3, at least 2: the fix's own
            R) (:meth:`ConsistencyMonitor.at_fix`). The 100-fix window reacts in about a
            second; measured with an undeclared 20 ms clock offset, the tracked rows beyond
            the 99 % bound came in runs of 0.1-0.15 s at a reach's onset before it had risen.
        settle_after_s: see ``settle_s`` (s; 0.05 s is five frames at 100 Hz).
        recent_fixes: see ``settle_s``.
        step_probability: a rigid-body fix fused with an NIS beyond the chi-square(3) quantile
            at this probability is a step below the gate, and the prediction it was fused with
            stays a rival hypothesis (:meth:`ConsistencyMonitor.cover_rivals`). At 1 - 1e-6
            (NIS 30.7) a consistent filter finds a false step once in 10^6 fixes (2.8 hours at
            100 Hz; at 0.999 it was once in 10 s of a clean simulated recording, each widening
            the bound for ``max_bridge_s``), while a 3-4 mm step against the 0.3 mm mocap noise
            has an NIS of 45-140.
        reacquisition_rival_s: how long (s) the prediction of a rigid-body fix ending a gap
            stays a rival (:meth:`ConsistencyMonitor.cover_rivals`; 0: never). On BROAD's real
            occlusions the frames within about 10 ms of one deviate from the motion more than
            the others (``benchmarks/occlusion_edges.py``), and from 35 ms on no more; a
            rigid body re-solved 4 mm off for the first 10 frames after every simulated gap
            put 4.9 % of the Tracker's rows beyond the 99 % bound (up to 4.7x) without the
            rival, 0.3 % (1.2x) with it. The cost is the bound of the first 0.2 s after each
            re-acquisition: on the BROAD trials with gaps cut every 1-2 s, the tracked rows'
            mean 99 % bound rose from 0.5-0.65 to 1.3-3.1 mm (median unchanged at 0.54-0.67,
            90th percentile 0.6-0.7 -> 3.1-4.6 mm; trials 01, 21, 24). A glitch longer than
            this is not covered (0.5 s of 4 mm: 13.7 % of rows beyond the bound). A body's
            first fixes have no prediction to keep: the model is not tested before a frame
            ``reacquisition_rival_s`` after the first one (:attr:`ConsistencyMonitor.
            model_tested`), and until then a row is its fix alone, within the window with the
            offset such a fix may carry (:meth:`ConsistencyMonitor.fix_only`).
        cause_std_scale: std scale above which a cause other than the mocap is named.
        early_max_std_scale: the refusal limit while fewer than ``minimum_shadow_gaps`` gaps
            are in (thin evidence: the matched scale is then about the largest row seen,
            which the next gap may well exceed). Measured with an undeclared 20 ms IMU clock
            offset: at 2 (the former limit) the Tracker bridged a gap 3.3 s in at std scale
            1.8 with errors up to 1.6x its bound (2.1 % of the run's rows beyond the 99 %
            bound); at 1.5, 0.2 %. Clean simulated recordings and the BROAD trials stay
            below it.
        gravity_error_fraction: mean acceleration error along gravity, as a fraction of |g|,
            above which gravity is suspected.
        motion_error_acceleration: RMS acceleration error (m/s^2) above which the IMU is said to
            disagree with the mocap motion.
        gap_end_window: real gaps (at most ``max_bridge_s``, ended by an accepted fix) whose
            ending fix the edge test reads (:meth:`ConsistencyMonitor.cover_rivals`): when
            the mean NIS of those fixes against their predictions, as the shadow gaps and the
            NIS window had scaled them, is beyond the windowed test's upper limit, the gaps
            start from fixes that were off, and until that mean is back to 3 the bound in a
            gap holds an offset on the fixes before it as large as the largest of them needed
            (and their ``mean NIS / 3`` scales the gap's covariance); the same window of
            occlusions holds the test of the fixes before them
            (:meth:`ConsistencyMonitor._gap_start`). Measured with the body drifting 1.5 mm
            off over the 5 frames before each occlusion (5 seeds of 30 s): 10.4 % of the
            Tracker's rows beyond the 99 % bound without the gap ends' test, 2.7 % with it
            (it fires after 2-7 gaps), 0.66 % with the test of the fixes before each gap too
            (it fires after 1-2), the gap ends' scale applied while either is on, and a fix's
            cover holding the offset whole (:meth:`ConsistencyMonitor.edge_offset_variance`).
        edge_s: how long before an occlusion the fixes may be off (s; ``edge_frames`` of
            them at the fixes' rate, 3 at 100 Hz): on BROAD's real occlusions the frames
            within about 10 ms of one deviate from the motion 1.3-2.3x more than the others,
            and from 35 ms on no more (``benchmarks/occlusion_edges.py``). The smoother's
            hold-out lengthens it where the data shows longer offsets
            (:func:`kfusion.kalman.smoother.edge_holdout`).
        longer_edges_s: further spans (s, each longer than ``edge_s``) over which the fixes
            before each occlusion are tested for an offset, each span its own windowed test
            (:meth:`ConsistencyMonitor._gap_start`). The test's signature assumes the offset
            starts at the span's first fix; by the last ``edge_s`` of a longer offset the
            filter has followed it, and those fixes' innovations hardly show it. Measured with
            the body 0.7 mm off on the 5 frames before each occlusion (simulated random_reach,
            30 s, seeds 0 and 1): with ``edge_s`` alone the test's mean T was 3.06 and 2.62
            (no offset: about 3) and 2.5 % and 5.0 % of the rows beyond the 99 % bound; tested
            over 50 ms too, 8.3 and 6.9, and 0.8 % and 2.4 % with the windows at 0.999 (0.5 %
            and 0.7 % at ``edge_test_probability``, 0.5 % and 0.6 % with 80 ms too). Over
            80 ms alone it fired on neither the 3- nor the 5-frame offsets reliably; as a
            third span it found 0.7 mm on 8 frames
            (seeds 0-4: 4.45 % -> 1.55 % beyond, mean) and turned on in no more of 40 clean
            seeds.
        edge_test_probability: two-sided probability of the windowed test of the fixes
            before occlusions (:meth:`ConsistencyMonitor._gap_start`; the NIS tests use
            ``nis_probability``). Each occlusion gives one value of T, so a window of them
            fills slowly, and a 0.7 mm offset (T about 6.5-8 against 3) failed the test at
            0.999 only after about 10 occlusions, every one before bridged from the offset
            fixes with a bound that knew nothing of it. A false alarm costs sharpness (the
            edge term on for a while), a miss the invariant, so the test is looser than the
            NIS tests. ``benchmarks/failsafe.py --seeds 5 --duration 30``, body 0.7 mm off on
            the 5 frames before each occlusion, rows beyond the 99 % bound (tracker; kalman
            the same within 0.1; spans 30 and 50 ms): 0.999: 3.5 % (simulated), 2.5 % (BROAD
            21 and 06); 0.99:
            0.9 % and 0.7 %; 0.95: 0.4 % and 0.5 %. On clean data
            (``benchmarks/bound_coverage.py``, 47 recordings) 0.99 changed nothing and 0.95
            turned the edge term on in 3 simulated recordings (median bound / error 2.0-2.1
            -> 2.4-2.6 kalman, 2.1 -> 2.8-3.3 smoother; pooled 3.18 -> 3.20 and 2.72 -> 2.77),
            in none of BROAD's. The cost is larger than that: a review found 3 of 40 clean
            simulated recordings where it fired after 1-3 occlusions and, switching off only
            when the window's mean is back to 3, stayed on for most of the recording, every
            tracked row's bound 2.3-2.8x wider.
        block_fixes: consecutive accepted fixes whose innovations the block test sums
            (:func:`block_nis`; ``nis_window // block_fixes`` blocks in its window, at least
            one). The fused position averages the last few fixes (R / P+ of them, about 4 at
            100 Hz with the mpu9255 profile); 8 spans twice that, so prediction errors that
            persist over the fixes it averages show in the sums.
        impact_memory_s: a gap is *near an impact* from an impact in it
            (:attr:`kfusion.kalman.KalmanFusion.last_impact_t`: a tap or knock, beyond
            :attr:`kfusion.kalman.KalmanParameters.impact_jerk`), or when its last fix came at
            most this long (s) after one. The shadow gaps' rows near an impact are matched
            apart from the others (:class:`HorizonScales`, one per class), and a gap near an
            impact takes :func:`near_impact_table`. With one scale for both, the knocks of
            BROAD trial 24 (tapping on a table) set the scale of every later gap (1.4 against
            0.3-0.5 before them): the gap rows' median bound / error was 5.2-7.5 over five gap
            placements, and a gap through a knock reached 2.6x its bound. Knocks come in
            episodes, with the arm working between them: with 0.3 s the gaps between the taps
            of an episode were matched with the calm parts' scale and 1.9 % of one
            placement's gap rows went beyond their 99 % bound (0.05 % with one scale); with
            2.5 s, the quiet class is the calm parts and every placement keeps at most 1 %
            (0.0-1.0 %, median bound / error 4.2-5.7; 0.0-0.7 % and 4.0-5.2 since the filter
            gives an impact's interval its own variance, :func:`kfusion.kalman.model.
            interpolation_variance`). Measured only on trial 24, the one recording here with
            knocks (``benchmarks/bound_coverage.py --gap-seeds 5``).
    """

    nis_window: int = 100
    nis_probability: float = 0.999
    shadow_window_s: float = 0.3
    shadow_period_s: float = 0.6
    horizon_edges_s: tuple[float, ...] = (0.02, 0.04, 0.06, 0.08, 0.1, 0.15, 0.2, 0.3)
    holdout_edges_s: tuple[float, ...] = (0.02, 0.04, 0.06, 0.08, 0.1, 0.15, 0.2, 0.3, 0.5)
    memory: int = 2000
    confidence: float = 0.99
    matching_quantile: float = 0.995
    minimum_shadow_gaps: int = 10
    minimum_scale: float = 0.04
    max_std_scale: float = 2.0
    clock_gaps: int = 100
    clock_tolerance_s: float = 0.005
    clock_sigmas: float = 3.0
    holdout_max_std_scale: float = 5.0
    settle_s: float = 0.2
    settle_after_s: float = 0.05
    recent_fixes: int = 5
    step_probability: float = 1.0 - 1e-6
    reacquisition_rival_s: float = 0.2
    cause_std_scale: float = 2.0
    early_max_std_scale: float = 1.5
    gravity_error_fraction: float = 0.5
    motion_error_acceleration: float = 2.0
    gap_end_window: int = 20
    edge_s: float = 0.03
    longer_edges_s: tuple[float, ...] = (0.05, 0.08)
    edge_test_probability: float = 0.95
    block_fixes: int = 8
    impact_memory_s: float = 2.5

    def __post_init__(self) -> None:
        positive = ("shadow_window_s", "shadow_period_s", "minimum_scale", "max_std_scale",
                    "holdout_max_std_scale", "settle_after_s", "early_max_std_scale", "edge_s")
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"MonitorParameters.{name}: expected a finite number > 0, "
                                 f"got {value!r}")
        for name in ("clock_tolerance_s", "clock_sigmas", "settle_s", "reacquisition_rival_s",
                     "impact_memory_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"MonitorParameters.{name}: expected a finite number >= 0, "
                                 f"got {value!r}")
        for name in ("nis_window", "memory", "minimum_shadow_gaps", "clock_gaps",
                     "recent_fixes", "gap_end_window", "block_fixes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"MonitorParameters.{name}: expected an integer >= 1, "
                                 f"got {value!r}")
        for name in ("nis_probability", "confidence", "matching_quantile", "step_probability",
                     "edge_test_probability"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or (not 0.0 < value < 1.0
                        and not (name == "matching_quantile" and value == 1.0)):
                raise ValueError(f"MonitorParameters.{name}: expected a probability in (0, 1), "
                                 f"got {short_repr(value)}")
        for name in ("horizon_edges_s", "holdout_edges_s"):
            edges = tuple(float(edge) for edge in getattr(self, name))
            if not edges or any(b <= a for a, b in zip(edges, edges[1:], strict=False)) \
                    or edges[0] <= 0:
                raise ValueError(f"MonitorParameters.{name}: expected increasing positive "
                                 f"times, got {getattr(self, name)!r}")
            object.__setattr__(self, name, edges)
        if not _spans_after(self.edge_s, self.longer_edges_s):
            raise ValueError(f"MonitorParameters.longer_edges_s: expected increasing times "
                             f"longer than edge_s ({self.edge_s}; () tests edge_s alone), got "
                             f"{short_repr(self.longer_edges_s)}")
        object.__setattr__(self, "longer_edges_s",
                           tuple(float(span) for span in self.longer_edges_s))
        if self.shadow_period_s < self.shadow_window_s:
            raise ValueError(f"MonitorParameters.shadow_period_s: expected >= shadow_window_s "
                             f"({self.shadow_window_s}), got {self.shadow_period_s}")

    @property
    def edge_spans_s(self) -> tuple[float, ...]:
        """The spans (s, increasing) over which the fixes before each occlusion are tested
        for an offset: ``edge_s``, then ``longer_edges_s``."""
        return (self.edge_s, *self.longer_edges_s)


def _spans_after(first: float, spans: object) -> bool:
    """True when ``spans`` is a tuple or list of finite real numbers (s), each longer than
    the one before, the first longer than ``first``."""
    if not isinstance(spans, (tuple, list)):
        return False
    previous = first
    for span in spans:
        if isinstance(span, bool) or not isinstance(span, (int, float)) \
                or not math.isfinite(span) or span <= previous:
            return False
        previous = span
    return True


def held_at_frame(peak: float, variance: NDArray[np.float64]) -> tuple[float, float]:
    """(factor, peak after the frame) for a bridged frame whose per-axis variances are
    ``variance`` (3,) m^2 (its covariance's diagonal), ``peak`` the largest per-axis variance
    an earlier frame of the same gap reported (0 at the gap's start): the factor
    ``peak / max_i variance_i`` when that exceeds 1 (the frame's covariance times it reaches
    the peak, which stays), else 1 and the frame's largest variance is the new peak; a
    non-finite row neither takes nor sets it, and a factor that would overflow (or a zero
    variance) is not applied. Bounds that never shrink within a gap
    (:func:`kfusion.kalman.batch.held_in_gaps`): the batch filter and the Tracker both step
    the peak here, to the bit."""
    first, second, third = float(variance[0]), float(variance[1]), float(variance[2])
    if not (math.isfinite(first) and math.isfinite(second) and math.isfinite(third)):
        return 1.0, peak  # not a bound: it neither takes nor sets the peak
    largest = max(first, second, third)
    if peak > largest:
        factor = peak / largest if largest > 0.0 else 1.0
        return (factor if math.isfinite(factor) else 1.0), peak  # (never an inf bound)
    return 1.0, largest


@dataclass(frozen=True)
class MonitorReport:
    """What the monitor found (health / diagnostics).

    Attributes:
        nis: the windowed NIS test over the last accepted fixes.
        shadow_gaps: shadow gaps completed.
        variance_scale: (bins,) covariance scale per horizon bin (NaN: no evidence yet), matched
            on the shadow-gap rows away from impacts.
        std_scale: largest standard-deviation scale the shadow gaps' innovations needed, or
            the NIS matching factor's (>= sqrt(minimum_scale)); the refusal rule reads it.
        bridging_allowed: False when the monitor refuses to bridge (gaps are ``lost``).
        suspected_cause: one of :data:`CAUSES`.
        clock_offset_s, clock_offset_std_s: the IMU clock offset the shadow gaps show
            (positive: the IMU clock behind the mocap) and its 1-sigma, s
            (:meth:`ConsistencyMonitor.clock_offset`; NaN before 3 gaps with motion).
        steps: fixes fused with an NIS beyond the ``step_probability`` quantile whose
            prediction was kept as a rival (steps below the gate: a shifted marker cluster,
            or motion the IMU did not show).
        edge_offset_std_m: 1-sigma per axis (m) of an offset on the fixes before a gap that the
            last real gaps' ends or the fixes before them showed
            (:meth:`ConsistencyMonitor.cover_rivals`; 0 while both agree with the model).
        gap_start_statistic: the mean of the statistic T of the fixes before the last
            ``gap_end_window`` occlusions (:func:`edge_offset_evidence`, each divided by the
            NIS window's matching factor while the windowed NIS test fails high; chi-square(3),
            mean 3, without an offset on them), the largest over the spans tested
            (``MonitorParameters.edge_s`` and ``longer_edges_s``), NaN before the first.
        impact_variance_scale: (bins,) the same as ``variance_scale``, matched on the rows
            near impacts (``MonitorParameters.impact_memory_s``; NaN: none yet).
    """

    nis: NisTest
    shadow_gaps: int
    variance_scale: tuple[float, ...]
    std_scale: float
    bridging_allowed: bool
    suspected_cause: str
    clock_offset_s: float = math.nan
    clock_offset_std_s: float = math.nan
    steps: int = 0
    edge_offset_std_m: float = 0.0
    gap_start_statistic: float = math.nan
    impact_variance_scale: tuple[float, ...] = ()

    def as_dict(self) -> dict[str, object]:
        """Plain dict for health output."""
        return {"nis_mean": self.nis.mean, "nis_consistent": self.nis.consistent,
                "shadow_gaps": self.shadow_gaps, "variance_scale": list(self.variance_scale),
                "std_scale": self.std_scale, "bridging_allowed": self.bridging_allowed,
                "suspected_cause": self.suspected_cause, "clock_offset_s": self.clock_offset_s,
                "clock_offset_std_s": self.clock_offset_std_s, "steps": self.steps,
                "edge_offset_std_m": self.edge_offset_std_m,
                "gap_start_statistic": self.gap_start_statistic,
                "impact_variance_scale": list(self.impact_variance_scale)}


class HorizonScales:
    """Per-bin memory of the scales the rows of the last gaps needed, and the matched scales.

    Shared by the online monitor (shadow gaps of the filter) and the smoother's offline
    hold-out (:func:`kfusion.kalman.smoother.run_smoother`). Besides each bin's rows in arrival
    order (the last ``memory``), it keeps their finite values sorted and counts the infinite
    ones, so that a bin's matched scale (:func:`quantile_matching_scale` of its rows) is read
    without sorting the rows again: a monitored run matches the scales after every shadow gap."""

    def __init__(self, params: MonitorParameters) -> None:
        self.params = params
        bins = len(params.horizon_edges_s)
        self._rows: list[deque[float]] = [deque(maxlen=params.memory) for _ in range(bins)]
        self._sorted: list[list[float]] = [[] for _ in range(bins)]  # each bin's finite rows
        self._unbounded = [0] * bins  # each bin's infinite rows
        self.gaps = 0
        self._table: NDArray[np.float64] | None = None  # cache of scale_table()
        self._largest = math.nan  # its largest entry, with it

    def add_gap(self, horizons_s: ArrayLike, required: ArrayLike) -> None:
        """One gap's rows: horizon (k,) s and the scale each row needed (k,)."""
        horizons = np.asarray(horizons_s, dtype=float)
        values = np.asarray(required, dtype=float)
        if len(horizons) == 0:
            return
        for horizon, value in zip(horizons.tolist(), values.tolist(), strict=True):
            index = horizon_bin(horizon, self.params.horizon_edges_s)
            rows = self._rows[index]
            if len(rows) == rows.maxlen:  # the oldest row leaves the memory
                self._forget(index, rows[0])
            rows.append(value)
            if math.isinf(value):
                self._unbounded[index] += 1
            elif not math.isnan(value):
                bisect.insort(self._sorted[index], value)
        self.gaps += 1
        self._table = None

    def _forget(self, index: int, value: float) -> None:
        """Drop ``value``, a row of bin ``index`` leaving the memory, from its sorted rows or
        its count of infinite ones."""
        if math.isinf(value):
            self._unbounded[index] -= 1
        elif not math.isnan(value):
            ordered = self._sorted[index]
            del ordered[bisect.bisect_left(ordered, value)]

    def copy(self) -> HorizonScales:
        """An independent copy (the rows are floats). The scale table is computed first and
        shared (it is read-only), so a copy restored again and again does not recompute it."""
        other = HorizonScales.__new__(HorizonScales)
        other.params = self.params
        other._rows = [deque(rows, maxlen=rows.maxlen) for rows in self._rows]
        other._sorted = [list(rows) for rows in self._sorted]
        other._unbounded = list(self._unbounded)
        other.gaps = self.gaps
        other._table = self.scale_table()
        other._largest = self._largest
        return other

    def variance_scales(self) -> tuple[float, ...]:
        """Matched variance scale per bin (NaN where the bin has no evidence), before limits:
        :func:`quantile_matching_scale` of each bin's rows, read from its sorted rows."""
        confidence = self.params.matching_quantile
        scales = []
        for ordered, unbounded in zip(self._sorted, self._unbounded, strict=True):
            count = len(ordered) + unbounded
            if count == 0:
                scales.append(math.nan)
            elif unbounded and unbounded / count > 1.0 - confidence:
                scales.append(math.inf)
            else:
                scales.append(linear_quantile(ordered, confidence))
        return tuple(scales)

    def scale_table(self) -> NDArray[np.float64]:
        """(bins,) variance scale applied per bin: the matched scale, at least ``minimum_scale``
        (at least 1 before ``minimum_shadow_gaps`` gaps, and in a bin with fewer rows than
        :func:`rows_to_shrink`); a bin without evidence takes the largest scale of the bins
        before it (1 if none)."""
        if self._table is not None:
            return self._table
        params = self.params
        floor = params.minimum_scale if self.gaps >= params.minimum_shadow_gaps else 1.0
        enough = rows_to_shrink(params.matching_quantile)
        table = []
        previous = floor
        for scale, rows in zip(self.variance_scales(), self._rows, strict=True):
            bin_floor = floor if len(rows) >= enough else max(floor, 1.0)
            value = previous if math.isnan(scale) else max(scale, bin_floor)
            table.append(value)
            previous = max(previous, value)
        self._table = np.asarray(table, dtype=float)
        self._table.flags.writeable = False
        self._largest = max(table)
        return self._table

    def largest_scale(self) -> float:
        """The largest scale of :meth:`scale_table` (its entries are never NaN)."""
        self.scale_table()
        return self._largest

    def scale_at(self, horizons_s: ArrayLike) -> NDArray[np.float64]:
        """Variance scale at each horizon (s)."""
        return self.scale_table()[horizon_bins(horizons_s, self.params.horizon_edges_s)]


def near_impact(last_impact_t: float, fix_t: float, memory_s: float) -> bool:
    """True when a gap whose last fix came at ``fix_t`` (s) is near an impact: the last one
    (``last_impact_t``, s; -inf: none) came after the fix or at most ``memory_s`` before it
    (``MonitorParameters.impact_memory_s``)."""
    return last_impact_t >= fix_t - memory_s


def near_impact_table(near: HorizonScales, quiet: HorizonScales) -> NDArray[np.float64]:
    """(bins,) the variance scale per horizon bin of a gap near an impact: ``near``'s table
    (:meth:`HorizonScales.scale_table`, with its limits while its evidence is thin), and at
    least the scale ``quiet`` matched where it has rows (:meth:`HorizonScales.
    variance_scales`; a bin without them adds nothing): a gap near an impact is never given
    less than the gaps away from them showed they need, and a recording knocked throughout
    (no rows away from impacts) is not held at the thin-evidence limit of an empty class."""
    return np.fmax(near.scale_table(), np.asarray(quiet.variance_scales(), dtype=float))


class ConsistencyMonitor:
    """Windowed NIS and shadow gaps beside a running :class:`~kfusion.kalman.KalmanFusion`.

    Feed it the same IMU samples as the filter (:meth:`imu`), and after each mocap frame the
    filter's outcome (:meth:`mocap`). ``shadow`` is a second filter built with the same
    configuration; the monitor restores it from the main filter's snapshots and never touches
    the main filter.
    """

    def __init__(self, shadow: KalmanFusion, params: MonitorParameters | None = None,
                 gravity: ArrayLike = (0.0, 0.0, -9.81)) -> None:
        self.params = params if params is not None else MonitorParameters()
        self._shadow = shadow
        self._gravity = np.asarray(gravity, dtype=float)
        self._scales = HorizonScales(self.params)  # the shadow rows' prediction scales
        # the same for the rows near an impact (impact_memory_s), kept apart; whether the
        # running gap is near one, from the main filter's last_impact_t (s) at the last frame
        self._impact_scales = HorizonScales(self.params)
        self._near_impact = False
        self._innovation_scales = HorizonScales(self.params)  # their innovation scales
        self._nis: deque[float] = deque(maxlen=self.params.nis_window)
        # their sum held exactly (add_exactly; None: to be summed again), so that the window's
        # mean is read without summing it at every fused fix
        self._nis_partials: list[float] | None = []
        # the block test (block_nis): the running block's sums of y (3,) m and S (3, 3) m^2 and
        # its fixes (each sum built new, never changed in place: snapshots share them), and the
        # last nis_window // block_fixes blocks' NIS
        self._block_y = _NO_Y
        self._block_S = _NO_S
        self._block_count = 0
        self._block_nis: deque[float] = deque(
            maxlen=max(1, self.params.nis_window // self.params.block_fixes))
        self._block_on = False  # the block test failed high, its mean not yet back to 3
        # the fixes that ended the last gap_end_window real gaps: their NIS, and the edge
        # offset variance each needed (edge_variance_needed); _edge_variance reads them
        self._gap_end_nis: deque[float] = deque(maxlen=self.params.gap_end_window)
        self._gap_end_edge: deque[float] = deque(maxlen=self.params.gap_end_window)
        self._edge_value: float | None = None  # _edge_variance(), None: not computed
        self._edge_on = False  # the gap ends' test failed high, not yet back to 3 (_gap_end)
        # the fixes before the last gap_end_window occlusions (_gap_start), per span tested
        # (edge_s, then longer_edges_s; NaN: the run before that occlusion was shorter): the
        # edge offset test's statistic (edge_offset_evidence) and the offset variance each
        # needed, and the innovations (y (3,) m, S (3, 3) m^2) of the last fixes of the running
        # run, as many as the longest span holds
        self._gap_start_statistic: deque[tuple[float, ...]] = \
            deque(maxlen=self.params.gap_end_window)
        self._gap_start_edge: deque[tuple[float, ...]] = deque(maxlen=self.params.gap_end_window)
        # per span: its test failed high, not yet back to 3 (_gap_start)
        self._gap_start_on = (False,) * len(self.params.edge_spans_s)
        self._run_innovations: deque[tuple[NDArray[np.float64], NDArray[np.float64]]] = \
            deque(maxlen=1)
        self._edge_frames_period = math.nan  # _edge_frame_counts' rounded period, s, and counts
        self._edge_frames_counts: tuple[int, ...] = ()
        self._fix_period = math.inf  # s between the last two fixes in a run (not a gap)
        # values derived from _nis and _scales, kept until those change (in mocap(), at a fused
        # fix and when a shadow gap closes) or a restore replaces them with the snapshot's own
        # (None: not computed yet). Each is built new, never changed in place: snapshots share
        # them (_copy_state).
        self._nis_window_value: tuple[float, float] | None = None  # _nis_window()
        self._scale_table_value: NDArray[np.float64] | None = None  # scale_table(), read-only
        self._std_scale_value: float | None = None  # _std_scale()
        self._bridging_value: bool | None = None  # bridging_allowed
        self._widening_value: tuple[float, float] | None = None  # _fix_widening() at the fix
        self._start: float | None = None  # time of the running shadow gap's last fix
        self._next_start = -math.inf
        # the running shadow gap's rows: horizon s, error (3,) m, the shadow's covariance (3, 3)
        # m^2 and the fix's noise variance m^2 (their scales are computed when it closes)
        self._rows_h: list[float] = []
        self._rows_error: list[NDArray[np.float64]] = []
        self._rows_covariance: list[NDArray[np.float64]] = []
        self._rows_noise: list[float] = []
        self._rows_velocity: list[NDArray[np.float64]] = []  # shadow velocity change, m/s
        self._rows_impact: list[bool] = []  # the row is near an impact (impact_memory_s)
        self._start_velocity = np.zeros(3)  # the shadow's velocity at the gap's fix, m/s
        # the last gaps' gap_clock_evidence (a tuple: shared, not copied, by snapshots)
        self._clock_evidence: tuple[tuple[float, float], ...] = ()
        self._accelerations: deque[NDArray[np.float64]] = deque(maxlen=self.params.nis_window)
        self._last_fix: tuple[float, NDArray[np.float64]] | None = None  # (t s, position (3,) m)
        self._fix_horizon = math.inf  # s from the fix before the last one to it (its prediction)
        # (t s, s since the rigid-body fix before it) of the last fused frame, with or without a
        # rigid-body fix of its own: marker-level fusion fuses frames of 1-2 markers, which have
        # none, and correct the prediction only in part, so its horizon runs from the last fix
        self._fused = (-math.inf, math.inf)
        self._settle_until = -math.inf  # fixes until this time get _settle_factor (settle_s), s
        self._settle_factor = 1.0
        self._recent_nis: deque[float] = deque(maxlen=self.params.recent_fixes)
        self._gated_fix: NDArray[np.float64] | None = None  # newest fix gated since the last fused
        # (t s, offset (3,) m, covariance (3, 3) m^2) of the prediction a fix replaced after gating
        self._rival: tuple[float, NDArray[np.float64], NDArray[np.float64]] | None = None
        # the same, (t s, offset (3,) m, innovation covariance (3, 3) m^2, until s), for the
        # predictions of fixes fused with an NIS beyond its quantile at step_probability (steps
        # in the fixes below the gate: _step) and of fixes ending a gap (_reacquisition_rival),
        # each kept until its time; none smaller and sooner over than another (a tuple: shared,
        # not copied, by snapshots)
        self._steps: tuple[tuple[float, NDArray[np.float64], NDArray[np.float64], float],
                           ...] = ()
        self._step_count = 0  # fixes taken as steps (MonitorReport.steps)
        self._tested_fixes = 0  # fixes compared with a prediction (model_tested)
        self._first_fix_t = math.inf  # time of the first fused frame, s (model_tested)
        self._appeared = False  # a fused frame came reacquisition_rival_s after it or later

    # -------------------------------------------------------------- events

    def imu(self, t: float, accelerometer: ArrayLike, gyroscope: ArrayLike) -> None:
        """An IMU sample the main filter was given (s, m/s^2, rad/s)."""
        if self._start is not None:
            self._shadow.predict(t, accelerometer, gyroscope)

    @property
    def gap_shadow(self) -> KalmanFusion | None:
        """The shadow filter while a shadow gap runs (the filter :meth:`imu` predicts), else
        None. A caller may predict it itself in place of :meth:`imu`, with the same sample as
        the main filter (the compiled engine does both in one kernel call: :meth:`kfusion.
        kalman.compiled_fusion.CompiledFusion.predict_valid_with`); the monitor's own state
        does not change at IMU samples either way."""
        return self._shadow if self._start is not None else None

    @property
    def takes_checked_samples(self) -> bool:
        """True when the shadow filter has the compiled engine's checked entry
        (``predict_valid``), so a caller may predict :attr:`gap_shadow` with it."""
        return hasattr(self._shadow, "predict_valid")

    def wants_prior(self, t: float, seen: bool) -> bool:
        """True when :meth:`mocap` needs the filter's estimate before a frame at t (s) that
        carries a fix (``seen``: a visible position or markers; a frame without one never
        uses it): a fix was gated since the last fused one, or the frame would end a gap
        (:func:`reacquired_after_gap`; see :meth:`cover_rivals`)."""
        return seen and (self._gated_fix is not None or (
            self._last_fix is not None and self.params.reacquisition_rival_s > 0
            and reacquired_after_gap(t - self._last_fix[0], self.params.settle_after_s)))

    def mocap(self, t: float, position: NDArray[np.float64] | None, outcome: UpdateOutcome,
              fusion: KalmanFusion, prior: FilterEstimate | None = None) -> None:
        """A mocap frame at t (s) after the main filter (``fusion``) processed it with
        ``outcome``; ``position`` (3,) m or None when occluded; ``prior``: the filter's
        estimate at t before this frame (needed only when :meth:`wants_prior`)."""
        self._widening_value = None  # the state changes from here
        kind, nis, params = outcome.kind, outcome.nis, self.params
        last_impact = fusion.last_impact_t
        near = self._last_fix is not None and \
            near_impact(last_impact, self._last_fix[0], params.impact_memory_s)
        if near != self._near_impact:  # (the gap this frame continues or ends)
            self._near_impact = near
            self._scale_table_value = None
        self._gap_start(t, position, outcome)  # before _last_fix takes this frame
        if kind == INITIALISED and self._first_fix_t != math.inf:
            # the filter forgot its state (a reset: an overflow, or a prediction beyond
            # FORGOTTEN_POSITION_STD) and this fix starts it again: its first fixes are a
            # recording's first (model_tested), with nothing before them to compare with
            self._first_fix_t, self._appeared, self._tested_fixes = math.inf, False, 0
            self._bridging_value = None
        if kind in USED_OUTCOMES:
            if self._first_fix_t == math.inf:
                self._first_fix_t = t
            if not self._appeared and t - self._first_fix_t >= params.reacquisition_rival_s:
                self._appeared = True  # model_tested from here
                self._bridging_value = None
        if kind in (ACCEPTED, REACQUIRED) and math.isfinite(nis) and not self.model_tested \
                and self._informative(t, fusion):
            self._tested_fixes += 1  # compared with a tight prediction (model_tested)
            self._bridging_value = None
        if kind == ACCEPTED and math.isfinite(nis):
            self._add_to_block(t, outcome)
            leaving = self._nis[0] if len(self._nis) == self._nis.maxlen else None
            self._nis.append(nis)
            partials = self._nis_partials
            if partials is not None and not (
                    add_exactly(partials, nis)
                    and (leaving is None or add_exactly(partials, -leaving))):
                self._nis_partials = None
            self._forget_derived()
            self._recent_nis.append(nis)  # snapshots copy it (_copy_state)
            recent = sum(self._recent_nis)
            dof = 3 * len(self._recent_nis)
            if len(self._recent_nis) == params.recent_fixes and \
                    recent > chi2_quantile(params.nis_probability, dof):
                self._settle(t, recent / dof)
        if kind in USED_OUTCOMES:  # before _last_fix takes this frame
            self._fused = (t, math.inf if self._last_fix is None else t - self._last_fix[0])
        if kind in USED_OUTCOMES and position is not None:
            self._fix_horizon = math.inf if self._last_fix is None else t - self._last_fix[0]
            if self._fix_horizon >= params.settle_after_s and \
                    nis > chi2_quantile(params.confidence, 3):
                self._settle(t, nis / 3.0)  # a gap's prediction was wrong
            if reacquired_after_gap(self._fix_horizon, params.settle_after_s):
                if kind == ACCEPTED and prior is not None:
                    self._gap_end(position, prior)
            elif math.isfinite(self._fix_horizon):
                self._fix_period = self._fix_horizon
            self._last_fix = (t, np.array(position, dtype=float))
            if self._gated_fix is not None and prior is not None \
                    and np.isfinite(prior.position).all():
                # fused after gated fixes: the prediction it replaced stays a rival hypothesis
                self._rival = (t, prior.position - np.asarray(position, dtype=float),
                               np.array(prior.position_covariance))
            elif kind in (ACCEPTED, REACQUIRED) and prior is not None \
                    and params.reacquisition_rival_s > 0 \
                    and reacquired_after_gap(self._fix_horizon, params.settle_after_s):
                # (its prior is known: an exact rival, also where the NIS makes it a step, for
                # which the posterior cannot give a loose prediction back)
                step = outcome.markers_used == 0 and \
                    nis > chi2_quantile(params.step_probability, 3)
                self._reacquisition_rival(t, position, prior, step)
            elif outcome.markers_used == 0 and \
                    nis > chi2_quantile(params.step_probability, 3):
                self._step(t, position, fusion)
            self._gated_fix = None
        elif kind == GATED and position is not None:
            self._gated_fix = np.array(position, dtype=float)
        if self._start is not None:
            self._shadow.update(t, None, None)
            horizon = t - self._start
            if kind == ACCEPTED and position is not None:
                estimate = self._shadow.estimate()
                error = np.asarray(position, dtype=float) - estimate.position
                self._rows_h.append(horizon)
                self._rows_error.append(error)
                self._rows_covariance.append(estimate.position_covariance)
                self._rows_noise.append(self._mocap_noise_variance())
                self._rows_velocity.append(estimate.velocity - self._start_velocity)
                self._rows_impact.append(
                    near_impact(last_impact, self._start, params.impact_memory_s))
            if horizon >= params.shadow_window_s or kind not in USED_OUTCOMES:
                self._close()
        if self._start is None and kind == ACCEPTED and t >= self._next_start:
            self._shadow.restore(fusion.snapshot())
            self._start_velocity = self._shadow.estimate().velocity
            self._start = t
            self._next_start = t + params.shadow_period_s

    def _step(self, t: float, position: NDArray[np.float64], fusion: KalmanFusion) -> None:
        """A rigid-body fix at t (s), ``position`` (3,) m, fused with an NIS beyond its
        chi-square quantile at ``step_probability``: a step between the fixes and the prediction,
        below the gate. Either the body moved as the IMU did not say, or the fixes moved
        without it (a marker of the cluster dropping out shifts the solved rigid body by a few
        mm for as long as it is missing). The filter follows the fixes within a few frames
        and its innovations shrink again either way, so they cannot settle it; the prediction
        the fix was fused with (recovered from the fused point, :func:`innovation_from_
        posterior`) stays a rival hypothesis for ``max_bridge_s`` (as long as that prediction
        would have been bridged); the bound covers the largest step still in time. The steps
        that follow while the filter takes the fixes in (its velocity overshoots: NIS of 15-40
        a few frames on) are smaller and change nothing until the first ends; when the fixes
        jump back, that step's prediction (the filter still on the shifted fixes, by up to the
        first step) is a rival too, and the filter follows the fixes back within a few frames
        (:meth:`cover_rivals`)."""
        estimate = fusion.estimate(t)
        found = innovation_from_posterior(position, estimate.position,
                                          estimate.position_covariance,
                                          self._shadow.params.mocap_position_noise ** 2)
        if found is None:
            return
        innovation, covariance = found
        self._keep_step(t, innovation, covariance, self._shadow.params.max_bridge_s)
        self._step_count += 1

    def _reacquisition_rival(self, t: float, position: NDArray[np.float64],
                             prior: FilterEstimate, step: bool = False) -> None:
        """A rigid-body fix at t (s), ``position`` (3,) m, ending a gap, fused with the prior
        estimate ``prior``: its prediction stays a rival like a step's (:meth:`_step`), whatever
        the NIS, with ``y = z - p-`` and ``S = P- + R``, for ``reacquisition_rival_s`` (at most
        ``max_bridge_s``). A rigid body re-solved while its cluster re-appears can be off by a
        few mm for a few frames, and that step's onset is hidden in the gap: the fix agrees with
        the loose prediction and the fixes after it agree with each other, so no NIS shows it.
        When the fixes jump back, that is a step (:meth:`_step`). A fix at least
        ``gate_min_innovation`` (1 cm) from the prediction, which the gate passed only because
        the prediction had grown loose, is a jump or a swap as a gated one may be, and a fix
        whose NIS makes it a ``step`` is one: their rivals last ``max_bridge_s``, as a step's
        (15 mm on the 20 frames after 0.5-1 s gaps: 7.4 % of the rows beyond the bound, up to
        32x, with 0.2 s), and a step is counted in :attr:`MonitorReport.steps`. Marker-level
        fixes (``position`` their Kabsch origin) are kept the same way."""
        predicted = np.asarray(prior.position, dtype=float)
        covariance = np.asarray(prior.position_covariance, dtype=float)
        if not (np.isfinite(predicted).all() and np.isfinite(covariance).all()):
            return
        shadow = self._shadow.params
        innovation = np.asarray(position, dtype=float) - predicted
        limit = shadow.max_bridge_s
        jump = step or float(innovation @ innovation) >= shadow.gate_min_innovation ** 2
        self._keep_step(t, innovation, 0.5 * (covariance + covariance.T)
                        + shadow.mocap_position_noise ** 2 * np.eye(3),
                        limit if jump else min(self.params.reacquisition_rival_s, limit))
        self._step_count += step

    def _keep_step(self, t: float, innovation: NDArray[np.float64],
                   covariance: NDArray[np.float64], lifetime_s: float) -> None:
        """Keep the prediction of a fix at t (s) with innovation y (3,) m and covariance S
        (3, 3) m^2 as a rival (offset -y) for ``lifetime_s`` s. The rivals still in time that
        are larger than it or outlive it stay (a smaller one over sooner never counts again)."""
        size = float(innovation @ innovation)
        until = t + lifetime_s
        kept = tuple(step for step in self._steps if t <= step[3] and (
            float(step[1] @ step[1]) > size or step[3] > until))
        self._steps = (*kept, (t, -innovation, covariance, until))

    def _step_rival(self, t: float) -> tuple[float, NDArray[np.float64], NDArray[np.float64]
                                             ] | None:
        """(t s, offset (3,) m, covariance (3, 3) m^2) of the largest step rival still in time
        at t (s) (:meth:`_step`, :meth:`_reacquisition_rival`), None if none."""
        largest: tuple[float, NDArray[np.float64], NDArray[np.float64]] | None = None
        size = -1.0
        for start, offset, covariance, until in self._steps:
            if start <= t <= until and float(offset @ offset) > size:
                largest, size = (start, offset, covariance), float(offset @ offset)
        return largest

    def _add_to_block(self, t: float, outcome: UpdateOutcome) -> None:
        """Add an accepted fix's innovation at t (s) to the running block (:func:`block_nis`);
        a fix that ends a gap (:func:`reacquired_after_gap`: its prediction spans the gap, and
        the gap-end tests judge it) or carries no innovation (not compared with a prediction)
        starts the next block instead. A full block's NIS joins the window."""
        y, S = outcome.y, outcome.S
        if y is None or S is None or self._last_fix is None or reacquired_after_gap(
                t - self._last_fix[0], self.params.settle_after_s):
            self._block_y, self._block_S, self._block_count = _NO_Y, _NO_S, 0
            return
        # new sums, never changed in place (snapshots share them)
        self._block_y = self._block_y + y
        self._block_S = self._block_S + S
        self._block_count += 1
        if self._block_count == self.params.block_fixes:
            value = block_nis(self._block_y, self._block_S)  # inf unless finite and regular
            self._block_y, self._block_S, self._block_count = _NO_Y, _NO_S, 0
            if math.isinf(value):
                return  # a non-finite innovation: the block is dropped
            blocks = self._block_nis
            blocks.append(value)
            self._block_on = failing_high(blocks, self.params.nis_probability, self._block_on)

    def _settle(self, t: float, factor: float) -> None:
        """Fixes up to ``settle_s`` after t (s) get at least ``factor`` (and 2), or the factor
        already running if larger (``settle_s``)."""
        running = self._settle_factor if t <= self._settle_until else 1.0
        self._settle_factor = max(running, factor, 2.0)
        self._settle_until = t + self.params.settle_s

    def _edge_shape(self, horizon_s: float) -> float:
        """``(a + b h)^2`` at ``horizon_s`` s into a gap (:func:`edge_sensitivity` for the
        fixes' period before it, over :meth:`_edge_shape_frames`); 0 before two fixes in a
        run."""
        # to 0.1 ms, so that jittered frame times share edge_sensitivity's cached solutions
        period = round(self._fix_period, 4)
        if not math.isfinite(period) or period <= 0:
            return 0.0
        shadow = self._shadow.params
        a, b = edge_sensitivity(shadow.accelerometer_noise_density,
                                shadow.mocap_position_noise, period, self._edge_shape_frames())
        return (a + b * horizon_s) ** 2

    def _edge_shape_frames(self) -> int:
        """Fixes an edge offset is taken to span (:meth:`_edge_shape`): those of the longest
        span whose gap-start test is on (the filter follows a longer offset further: at 100 Hz
        it carries 0.36 of a 3-frame one into the gap, 0.56 of a 5-frame one), else
        ``edge_s``'s."""
        counts = self._edge_frame_counts()
        frames = [count for count, on in zip(counts, self._gap_start_on, strict=False) if on]
        return max(frames) if frames else counts[0]

    def _gap_end(self, position: NDArray[np.float64], prior: FilterEstimate) -> None:
        """Keep the evidence of an accepted fix ending a real gap of ``_fix_horizon`` s (at most
        ``max_bridge_s``: a longer gap was not bridged) against the prediction ``prior``, with
        the prediction's covariance as the bound had it before this evidence: ``S = s P- + R``,
        s the shadow gaps' and the NIS window's scale at that horizon (what they already
        explain is not an edge offset). Keeps its NIS ``y^T S^-1 y`` and the edge offset
        variance it needed (:func:`edge_variance_needed`), and switches the edge term on when
        the mean NIS of the window fails the windowed test high, off when it falls back to its
        expectation (3) or below. Nothing is kept before the fixes' period is known (two fixes
        in a run): the offset's shape is not known then."""
        shape = self._edge_shape(self._fix_horizon)
        if shape <= 0 or not self._fix_horizon <= self._shadow.params.max_bridge_s:
            return
        innovation = np.asarray(position, dtype=float) - np.asarray(prior.position, dtype=float)
        covariance = np.asarray(prior.position_covariance, dtype=float)
        if not (np.isfinite(innovation).all() and np.isfinite(covariance).all()):
            return
        scale = self._binned(np.maximum(self._prediction_table(), self._nis_scale()),
                             self._fix_horizon)
        covariance = scale * 0.5 * (covariance + covariance.T) \
            + self._shadow.params.mocap_position_noise ** 2 * np.eye(3)
        self._gap_end_nis.append(normalised_error_squared(innovation, covariance))
        self._gap_end_edge.append(edge_variance_needed(innovation, covariance, shape,
                                                       self.params.confidence))
        self._edge_on = failing_high(self._gap_end_nis, self.params.nis_probability,
                                     self._edge_on)
        self._edge_value = None
        self._forget_derived(nis=False)  # the scale table reads _gap_end_scale

    def _gap_start(self, t: float, position: NDArray[np.float64] | None,
                   outcome: UpdateOutcome) -> None:
        """Keep the innovations of the last ``edge_frames`` accepted fixes of a run (a fix ending
        a gap starts a new run: its prediction spans the gap; a dropout shorter than
        ``settle_after_s`` does not end one); at the first frame ``settle_after_s`` or more
        after them (a real gap: single dropped frames do not fill the window), test them for
        an offset
        (:func:`edge_offset_evidence` with :func:`edge_innovation_signature`): keep the
        statistic T and the per-axis variance of the offset it shows, the moment estimate
        ``max(0, (|d^|^2 - tr J^-1) / 3)`` (``E|d^|^2 = |d|^2 + tr J^-1``; both with S times
        the NIS window's matching factor f while its test fails high: T / f and f J^-1; the
        variance
        :func:`edge_variance_needed` gives d^ against ``J^-1`` was far too small: d^ mostly
        lies inside J^-1's own 99 % ellipsoid), and switch the gap-start test on when the mean
        T of the last ``gap_end_window`` occlusions fails the windowed test high, off when it
        is back to 3 (:func:`failing_high`). Each span, ``edge_s`` and the
        ``longer_edges_s``, is tested over its own last fixes with its own signature, and
        has its own window and switch (at ``edge_test_probability``): an offset on 5 frames
        hardly shows in the last 3. Unlike the fix ending a gap, this comes
        ``settle_after_s`` into the gap, so the edge term can cover the rest of it."""
        kind, params = outcome.kind, self.params
        run, last = self._run_innovations, self._last_fix
        counts = self._edge_frame_counts()
        frames = counts[-1] if counts else 0  # the spans increase: the last is the longest
        ends_gap = last is not None and reacquired_after_gap(t - last[0], params.settle_after_s)
        if run and ends_gap:
            # the run has ended in a real gap (a dropout shorter than settle_after_s is none)
            if counts and len(run) >= counts[0]:
                self._test_gap_start(run, counts)
            run.clear()
        if frames == 0:  # the fixes' period is not known yet
            run.clear()
            return
        y, S = outcome.y, outcome.S
        if kind == ACCEPTED and position is not None and y is not None and S is not None \
                and last is not None and not ends_gap:
            # kept without a copy: every producer builds y and S new per update (the compiled
            # kernel's outputs, KalmanFusion's locals) or passes rows of the batch run's
            # arrays, which nothing writes after the kernel
            if run.maxlen != frames:
                run = self._run_innovations = deque(run, maxlen=frames)
            run.append((y, S))
            return
        if position is None and kind not in USED_OUTCOMES:
            return  # occluded: the run waits to see whether this is a real gap
        run.clear()

    def _test_gap_start(self, run: deque[tuple[NDArray[np.float64], NDArray[np.float64]]],
                        counts: tuple[int, ...]) -> None:
        """Test the last fixes before a real gap, ``run`` (y (3,) m, S (3, 3) m^2 each, oldest
        first), for a common offset over each span's last ``counts`` fixes (those it holds;
        :meth:`_gap_start`) and keep the results."""
        shadow, params = self._shadow.params, self.params
        # against S times the NIS window's factor, as the gap ends are tested against the
        # scaled predictions: innovations too large at every fix (mocap noisier than
        # configured, a lever arm) are no edge (unscaled, T averaged 5-7 on clean data with a
        # lever arm and the edge term was on for 47 % of the rows)
        factor = max(1.0, self._nis_scale())
        statistics, edges = [], []
        kept = list(run)
        for count in counts:
            found = None
            if count <= len(kept):
                fixes = kept[len(kept) - count:]
                signature = edge_innovation_signature(shadow.accelerometer_noise_density,
                                                      shadow.mocap_position_noise,
                                                      self._edge_frames_period, count)
                found = edge_offset_evidence([y for y, _ in fixes], [S for _, S in fixes],
                                             signature)
            if found is None:
                statistics.append(math.nan)
                edges.append(math.nan)
                continue
            statistic, offset, covariance = found
            statistics.append(statistic / factor)
            edges.append(max(0.0, (float(offset @ offset) - factor * float(np.trace(covariance)))
                             / 3.0))
        if all(math.isnan(value) for value in statistics):
            return
        self._gap_start_statistic.append(tuple(statistics))
        self._gap_start_edge.append(tuple(edges))
        was_on = self._gap_start_on
        self._gap_start_on = tuple(
            failing_high(_span_values(self._gap_start_statistic, span),
                         params.edge_test_probability, on) for span, on in enumerate(was_on))
        self._edge_value = None
        if any(self._gap_start_on) != any(was_on):  # the scale table reads _gap_end_scale
            self._forget_derived(nis=False)

    def _edge_frame_counts(self) -> tuple[int, ...]:
        """:func:`edge_frames` of ``edge_s`` and each of ``longer_edges_s`` at the fixes'
        period rounded as in :meth:`_edge_shape`, () before that period is known; computed
        again only when the rounded period changes (every frame reads them)."""
        period = round(self._fix_period, 4)
        if period != self._edge_frames_period:
            self._edge_frames_period = period
            self._edge_frames_counts = tuple(edge_frames(span, period)
                                             for span in self.params.edge_spans_s) \
                if math.isfinite(period) and period > 0 else ()
        return self._edge_frames_counts

    def _gap_ends_mean_nis(self) -> float:
        """The mean NIS of the fixes that ended the last ``gap_end_window`` real gaps while the
        edge term is on (:meth:`_gap_end`: the gaps' predictions were worse than their bound
        said; or :meth:`_gap_start`: the fixes before the gaps were off, so the gaps'
        predictions are suspect and their ends measure by how much, before their own test has
        enough of them), else 0 (also before a gap has ended)."""
        if not (self._edge_on or any(self._gap_start_on)) or not self._gap_end_nis:
            return 0.0
        return sum_mean(self._gap_end_nis)

    def _gap_end_scale(self) -> float:
        """The real gaps' matching factor ``mean NIS / 3`` while either edge test fails high
        (:meth:`_gap_ends_mean_nis`), else 0 (no constraint)."""
        return self._gap_ends_mean_nis() / 3

    def _edge_variance(self) -> float:
        """Variance (m^2 per axis) of an offset on the fixes before a gap that the bound in a
        gap allows for (:meth:`cover_rivals`): 0 while neither edge test is on (the fixes
        ending the last ``gap_end_window`` real gaps agree with their predictions,
        :meth:`_gap_end`, and the fixes before the last occlusions show no offset,
        :meth:`_gap_start`); else the larger of the ``matching_quantile`` of the variances the
        gap ends needed (:func:`edge_variance_needed`) and that of the gap starts' estimates
        over ``edge_s`` and over each longer span whose test is on (one quantile over both
        lists weighed their largest values less: up to 25 % below the gap ends' own)."""
        if self._edge_value is None:
            value = 0.0
            if self._edge_on or any(self._gap_start_on):
                quantile = self.params.matching_quantile
                kept = [list(self._gap_end_edge)] + [
                    _span_values(self._gap_start_edge, span)
                    for span, on in enumerate(self._gap_start_on) if span == 0 or on]
                matched = [quantile_matching_scale(values, quantile) for values in kept if values]
                value = max((scale for scale in matched if not math.isnan(scale)), default=0.0)
            self._edge_value = value
        return self._edge_value

    def _mocap_noise_variance(self) -> float:
        """R of the shadow innovation, m^2: the configured mocap noise, times the NIS matching
        factor when that is below 1 (at fixes R dominates S, so a small NIS says R is
        pessimistic; a pessimistic R would hide the shadow's error)."""
        configured = self._shadow.params.mocap_position_noise ** 2
        if len(self._nis) < self.params.nis_window:
            return configured
        return configured * min(1.0, self._nis_window()[0])

    def _close(self) -> None:
        """End the running shadow gap and keep its evidence."""
        if self._rows_h:
            innovation_scales, scales = shadow_rows_scales(
                np.array(self._rows_error), np.array(self._rows_covariance),
                self._rows_noise, self.params.confidence)
            # a new HorizonScales, never the one a snapshot may share (_copy_state); each row
            # to its class's (impact_memory_s)
            near = np.array(self._rows_impact, dtype=bool)
            horizons = np.array(self._rows_h)
            if not near.all():
                self._scales = self._scales.copy()
                self._scales.add_gap(horizons[~near], scales[~near])
            if near.any():
                self._impact_scales = self._impact_scales.copy()
                self._impact_scales.add_gap(horizons[near], scales[near])
            self._innovation_scales = self._innovation_scales.copy()
            self._innovation_scales.add_gap(self._rows_h, innovation_scales)
            self._forget_derived(nis=False)
            self._accelerations.append(fit_acceleration_error(self._rows_h,
                                                              np.array(self._rows_error)))
            clock = gap_clock_evidence(self._rows_h, self._rows_error, self._rows_velocity)
            if clock is not None:
                self._clock_evidence = (self._clock_evidence + (clock,))[
                    -self.params.clock_gaps:]
        self._start = None
        self._rows_h, self._rows_error, self._rows_covariance = [], [], []
        self._rows_noise = []
        self._rows_velocity = []
        self._rows_impact = []

    # -------------------------------------------------------------- results

    def variance_scale(self, horizon_s: float) -> float:
        """Factor for the position covariance at ``horizon_s`` s since the last fix: the shadow
        gaps' scale for that horizon and the NIS matching factor, whichever is larger."""
        return self._binned(self.scale_table(), horizon_s)

    def _binned(self, table: NDArray[np.float64], horizon_s: float) -> float:
        """``table``'s (bins,) scale at ``horizon_s`` s (:func:`horizon_bin`), at least 1 beyond
        the last bin (:func:`scale_beyond_evidence`)."""
        edges = self.params.horizon_edges_s
        scale = float(table[horizon_bin(horizon_s, edges)])
        # scale_beyond_evidence in floats (NaN stays NaN, as np.maximum keeps it)
        return 1.0 if horizon_s > edges[-1] and scale < 1.0 else scale

    def scale_table(self) -> NDArray[np.float64]:
        """(bins,) variance scale per horizon bin (:meth:`variance_scale` of each bin): the
        shadow gaps' scale and the NIS matching factor (read-only, computed once per change of
        the evidence) and, in a gap whose last fix was fused while recent innovations showed
        the predictions wrong (``settle_s``), their factor."""
        if self._scale_table_value is None:
            table = np.maximum(self._prediction_table(),
                               max(self._nis_scale(), self._gap_end_scale()))
            table.flags.writeable = False
            self._scale_table_value = table
        if self._last_fix is not None and self._last_fix[0] <= self._settle_until:
            return np.maximum(self._scale_table_value, self._settle_factor)
        return self._scale_table_value

    def _prediction_table(self) -> NDArray[np.float64]:
        """(bins,) the shadow gaps' variance scale per horizon bin for the running gap: the
        scales matched on the rows away from impacts, or, near an impact
        (``impact_memory_s``), :func:`near_impact_table`."""
        if not self._near_impact:
            return self._scales.scale_table()
        return near_impact_table(self._impact_scales, self._scales)

    def _nis_scale(self) -> float:
        """The NIS matching factor when the windowed test says the innovations are too large,
        else 0 (no constraint: a small NIS says R is pessimistic, not that P may shrink)."""
        return self._nis_window()[1]

    def _nis_window(self) -> tuple[float, float]:
        """(the NIS matching factor ``mean NIS / 3`` of the window (:func:`nis_matching_scale`,
        1 when empty), :meth:`_nis_scale`), from one mean over the window, computed once per
        fused fix (the batch driver and the Tracker read them at every row)."""
        if self._nis_window_value is None:
            # windowed_nis_test's mean and upper limit (mocap() keeps only finite NIS values,
            # so its finiteness filter has nothing to remove), nis_matching_scale's value
            # from the same mean (sum_mean)
            samples = len(self._nis)
            if samples == 0:
                self._nis_window_value = (1.0, 0.0)
            else:
                mean = self._window_mean(samples)
                upper = nis_interval(samples, self.params.nis_probability)[1]
                self._nis_window_value = (mean / 3, max(mean / 3 if mean > upper else 0.0,
                                                        self._block_scale()))
        return self._nis_window_value

    def _window_mean(self, samples: int) -> float:
        """:func:`sum_mean` of the NIS window (``samples`` values), the same bits, from its
        exactly held sum (:func:`add_exactly`) where that is valid."""
        partials = self._nis_partials
        if partials is not None:
            try:
                return math.fsum(partials) / samples
            except OverflowError:  # a correctly rounded sum beyond the largest float
                pass
        return sum_mean(self._nis)

    def _block_scale(self) -> float:
        """The block test's matching factor, ``mean block NIS / 3`` of the window
        (:func:`block_nis`), from when that mean fails the windowed test high until it is back
        to 3; else 0."""
        if not self._block_on:
            return 0.0
        return math.fsum(self._block_nis) / (3.0 * len(self._block_nis))

    def _forget_derived(self, nis: bool = True) -> None:
        """Drop the values derived from ``_scales`` and, with ``nis``, from ``_nis`` (after a
        change of them)."""
        if nis:
            self._nis_window_value = None
        self._widening_value = None
        self._scale_table_value = self._std_scale_value = self._bridging_value = None

    def fix_only(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """The position from the fixes alone, for when the IMU model is not trusted
        (:attr:`bridging_allowed` False): at the time of the last fused fix, that fix (3,) m
        with the mocap noise R = sigma_mocap^2 I (3, 3) m^2, times the innovations' factor of
        :meth:`at_fix` when that exceeds 1 (the mocap may be what is noisier); None at any
        other time (without a trusted motion model the position between fixes is unknown).
        Within ``reacquisition_rival_s`` of the first fused frame the fix may also be a body
        solved while its cluster appears, off by as much as the step rule lets through
        (:func:`step_offset_variance`, 2.7 R, added per axis): nothing came before it to
        compare with (:attr:`model_tested`). On simulated fixes with their 0.3 mm noise, the
        first 10 frames 3 mm off were 3.5-3.8x beyond R's bound; with the term 1.8-2.0x."""
        if self._last_fix is None or t != self._last_fix[0]:
            return None
        noise = self._shadow.params.mocap_position_noise ** 2
        # the innovations' factor (at_fix): when they are too large the mocap may be the part
        # that is noisier than configured, and the fix alone then has k R, not R
        _, factor = self._fix_widening(t)
        variance = factor * noise
        if t - self._first_fix_t < self.params.reacquisition_rival_s:
            variance = variance + step_offset_variance(noise, self.params)
        return self._last_fix[1].copy(), variance * np.eye(3)

    def at_fix(self, t: float, covariance: NDArray[np.float64]) -> NDArray[np.float64]:
        """The position covariance (3, 3) m^2 at the time of the last fused fix, t (s), with the
        prediction it was fused with taken as the monitor found it: at the scale the shadow
        gaps found for that prediction's horizon (:func:`fix_covariance_under_scale`), plus,
        while the windowed NIS test fails high, the excess its matching factor implies
        (:func:`fix_covariance_under_innovation_factor`) (R: the configured mocap noise, the
        gain's own); ``covariance`` unchanged at any other time (a gap: there the scale of
        :meth:`variance_scale` applies) or before a second fix (the first only initialises)."""
        scale, factor = self._fix_widening(t)
        if scale == 1.0 and factor == 1.0:
            return covariance
        return fix_covariances_widened(np.asarray(covariance, dtype=float)[None],
                                       self.fix_noise_variance, np.array([scale]),
                                       np.array([factor]))[0]

    @property
    def fix_noise_variance(self) -> float:
        """R = sigma_mocap^2 (m^2) of :meth:`at_fix`: the configured mocap noise, the gain's
        own."""
        return float(self._shadow.params.mocap_position_noise ** 2)

    def fix_widening(self, t: float) -> tuple[float, float]:
        """(scale, factor) that :meth:`at_fix` applies at t (s), each at least 1: the batch
        filter keeps them per row and widens its fixes at once
        (:func:`fix_covariances_widened`), with the bits of :meth:`at_fix`."""
        return self._fix_widening(t)

    def fix_scale(self, t: float) -> float:
        """Greater than 1 exactly when :meth:`at_fix` widens the covariance at t (s): the
        larger of the shadow gaps' scale for the last fused fix's prediction horizon and the
        NIS matching factor, when t is that fix's time, else 1 (callers skip forming the
        covariance)."""
        return max(self._fix_widening(t))

    def _fix_widening(self, t: float) -> tuple[float, float]:
        """(shadow-gap scale of the last fix's prediction, innovation factor), each at least
        1; (1, 1) unless t is that fix's time. The factor is the NIS matching factor while the
        windowed test fails high, and within ``settle_s`` of recent fixes whose innovations
        showed the predictions wrong, at least theirs (and 2: ``P+ + (R - P+)``, the fix's own
        R). A fix here is any fused frame, also one of marker-level fusion with 1-2 markers
        and so no rigid-body origin: with the IMU 8x slower and the block test on (factor 7.7),
        such rows kept the bare P+ and 33 of 106 were beyond the bound, up to 1.97x. The
        prediction's horizon runs from the last rigid-body fix: a frame of 1-2 markers corrects
        the prediction only in part (measured from the last fused frame instead, the 3-4-marker
        frames after such frames got bounds down to 0.64x and a few rows went beyond them)."""
        fused, horizon = self._fused
        if t != fused or math.isinf(horizon):
            return 1.0, 1.0
        if self._widening_value is None:  # at the last fused frame's time: kept until mocap()
            shadow = self._binned(self._prediction_table(), horizon)
            factor = max(1.0, self._nis_scale())
            if t <= self._settle_until:
                factor = max(factor, self._settle_factor)
            self._widening_value = (max(1.0, shadow), factor)
        return self._widening_value

    def cover_rivals(self, t: float, position: NDArray[np.float64],
                     covariance: NDArray[np.float64]) -> NDArray[np.float64]:
        """The position covariance (3, 3) m^2 at t (s) widened to cover the rival hypotheses
        the gate could not settle (a marker swap and a broken model look alike to it):

        * a fix gated since the last fused one may be right: with d = z_gated - position,
          P' = P + d d^T + R;
        * a fix fused after gated ones (a re-acquisition, or a swapped marker passing the gate
          once the prediction has grown loose) may be wrong: the prediction it replaced, d =
          x_prior - z and covariance P_prior, stays a rival for ``max_bridge_s`` (as long as
          that prediction would have been bridged): P' = P + d d^T + P_prior;
        * a fix fused with an NIS beyond its quantile (a step below the gate, :meth:`_step`)
          may be wrong the same way: its prediction, d = x_prior - z = -y, and the
          innovation's covariance S (the prior's and the fix's own noise) stay a rival for
          ``max_bridge_s``; so does the prediction of a rigid-body fix ending a gap, whatever
          its NIS (:meth:`_reacquisition_rival`: d = x_prior - z, S = P_prior + R); of those
          still in time, the largest: P' = P + d d^T + S.

        * at and after the last fused fix, an offset on the fixes up to it, once either edge
          test showed one (:meth:`edge_offset_variance`): P' = P + v I, v = min(sigma^2,
          sigma_step^2) at the fix and ``max(that, sigma^2 (a + b h)^2)`` h s after it.

        The largest eigenvalue of P' is at least |d|^2, so the bound reaches past the rival.
        Unchanged when there is none."""
        params = self._shadow.params
        if self._gated_fix is not None:
            difference = self._gated_fix - np.asarray(position, dtype=float)
            covariance = (covariance + np.outer(difference, difference)
                          + params.mocap_position_noise ** 2 * np.eye(3))
        for rival in (self._rival, self._step_rival(t)):
            if rival is not None and t - rival[0] <= params.max_bridge_s:
                _, offset, rival_covariance = rival
                covariance = covariance + np.outer(offset, offset) + rival_covariance
        edge = self.edge_offset_variance(t)
        if edge > 0:
            covariance = covariance + edge * np.eye(3)
        return covariance

    def edge_offset_variance(self, t: float) -> float:
        """Per-axis variance (m^2) at t (s) at or after the last fused fix from an offset on the
        fixes before it: ``sigma^2 (a + b h)^2`` h s after it (:meth:`_edge_variance`,
        :func:`edge_sensitivity`), 0 before it and while neither edge test is on
        (:meth:`_edge_variance`). At the fix itself (h = 0) ``min(sigma^2, sigma_step^2)``:
        online no fix is known to be the last before an occlusion until the occlusion comes,
        so every fix holds the offset while the edge term is on. Whole, not the share ``a``
        (0.36 at 100 Hz) that :func:`edge_sensitivity` gives for a step on the last
        ``edge_frames`` fixes: an offset that builds up over more frames is followed further
        (the filter tracks a slow drift with little lag), and with the body drifting 1.5 mm
        over 5 frames the fused position at the last fix carried 0.6-0.7 of it; with ``a^2``
        those fixes were 0.5 % of the rows beyond the bound, up to 2.0x, and 0.06 % without it.
        sigma^2 is matched on the gap ends, where the IMU's own errors weigh in (one ordinary
        miss at a gap end set 4.3 mm for 1.5 mm offsets, and every fix's bound 9x wider); at a
        fix it is capped by :func:`step_offset_variance`, since a larger offset is a step and
        the step rule already keeps its prediction as a rival."""
        if self._last_fix is None or t < self._last_fix[0]:
            return 0.0
        variance = self._edge_variance()
        if variance <= 0:
            return 0.0
        at_fix = min(variance, step_offset_variance(
            self._shadow.params.mocap_position_noise ** 2, self.params))
        horizon = t - self._last_fix[0]
        if horizon == 0.0:
            return at_fix
        return max(at_fix, variance * self._edge_shape(horizon))

    def has_rivals(self, t: float) -> bool:
        """True when :meth:`cover_rivals` widens a covariance at t (s): a fix was gated since
        the last fused one, a fix fused after gated ones is younger than ``max_bridge_s``, or an
        edge offset applies (callers skip forming the point and covariance otherwise)."""
        if self._gated_fix is not None:
            return True
        limit = self._shadow.params.max_bridge_s
        if self._rival is not None and t - self._rival[0] <= limit:
            return True
        if self._steps:
            step = self._step_rival(t)
            if step is not None and t - step[0] <= limit:
                return True
        return self.edge_offset_variance(t) > 0

    @property
    def bridging_allowed(self) -> bool:
        """False when the shadow gaps need a larger std scale than ``max_std_scale``, or, while
        fewer than ``minimum_shadow_gaps`` gaps are in, one above ``early_max_std_scale`` (thin
        evidence of a broken model: its scale is not yet known well enough to bridge on); and
        before ``recent_fixes`` fixes have been compared with the model's predictions (an
        untested model: with the gravity sign flipped, a gap after the first 2-3 fixes was
        bridged 800-940 mm off with a 40-50 mm bound, before any NIS could show it)."""
        if self._bridging_value is None:
            self._bridging_value = self.model_tested and \
                bridging_allowed(self._std_scale(), self._innovation_scales.gaps, self.params)
        return self._bridging_value

    @property
    def model_tested(self) -> bool:
        """True once ``recent_fixes`` fixes have been compared with predictions tight enough
        to test the model (:meth:`_informative`; ``accepted`` or ``reacquired``) and a frame
        has been fused ``reacquisition_rival_s`` after the first fused frame or later: before,
        :attr:`bridging_allowed` is False because the model is untested, not because the data
        refused it, and a row with a fix is that fix alone (:meth:`fix_only`). Right after the
        first fix (or a reset) the velocity is barely known, the predictions are loose and
        their NIS small whatever the model: with the IMU rotated 90° on the forearm, the first
        5 fixes after a reset let a gap be bridged 590 mm off with a 35 mm bound. A body seen
        too rarely for a tight prediction (one frame in 0.6 s) is never tested, and never
        bridged.

        The first fixes of a body are what a fix ending a gap is (a rigid body solved while its
        cluster appears can be off by a few mm for a few frames), with no prediction before
        them to keep as a rival (:meth:`_reacquisition_rival`), and the fixes right after
        agree with them, so the posterior built on them is not shown before the window has
        passed: BROAD trial 21 starts occluded, and with its first 10 frames 3 mm off the
        posterior's bound claimed them at 4.4x below the error (``benchmarks/failsafe.py``).
        The fixes inside the window still count as tests (a body seen for less than the
        window and then only sparsely is tested at its first frame after it)."""
        return self._appeared and self._tested_fixes >= self.params.recent_fixes

    def _informative(self, t: float, fusion: KalmanFusion) -> bool:
        """True when the fix just fused at t (s) was predicted tightly enough to test the
        model: the update's gain ``K = P+ R^-1`` (position block, R = r I) has its largest
        eigenvalue at most 0.9, i.e. the prediction's covariance was at most 9 R
        (:func:`innovation_from_posterior`'s limit)."""
        noise = self._shadow.params.mocap_position_noise ** 2
        covariance = np.asarray(fusion.estimate(t).position_covariance, dtype=float)
        if not (noise > 0 and np.isfinite(covariance).all()):
            return False
        return float(np.linalg.eigvalsh(0.5 * (covariance + covariance.T))[-1]) <= 0.9 * noise

    def clock_offset(self) -> tuple[float, float] | None:
        """(offset s, 1-sigma s) of the IMU clock the shadow gaps show (positive: the IMU clock
        behind the mocap; :func:`clock_offset_estimate`), None before 3 gaps with motion."""
        return clock_offset_estimate(self._clock_evidence)

    @property
    def clock_suspect(self) -> bool:
        """True once ``minimum_shadow_gaps`` gaps show a clock offset beyond
        ``clock_tolerance_s`` by more than ``clock_sigmas`` of its 1-sigma (a diagnostic: see
        the module docstring)."""
        if len(self._clock_evidence) < self.params.minimum_shadow_gaps:
            return False
        found = self.clock_offset()
        if found is None:
            return False
        offset, std = found
        return abs(offset) > self.params.clock_tolerance_s + self.params.clock_sigmas * std

    def _std_scale(self) -> float:
        """The std scale the refusal rule reads: the shadow innovations' largest matched
        variance scale or the NIS matching factor, square-rooted."""
        if self._std_scale_value is None:
            largest = self._innovation_scales.largest_scale()
            self._std_scale_value = math.sqrt(max(largest, self._nis_scale()))
        return self._std_scale_value

    def snapshot(self) -> object:
        """A copy of the monitor's state; :meth:`restore` continues from it exactly."""
        return self.state_snapshot(), self.shadow_snapshot()

    def state_snapshot(self) -> object:
        """The part of :meth:`snapshot` besides the shadow filter: it changes only in
        :meth:`mocap` and :meth:`restore` (and the values derived from it, cached at reads),
        so a caller may keep one and pair it with later :meth:`shadow_snapshot` s until the
        next of those calls."""
        state = vars(self).copy()
        for key in _NOT_STATE:
            del state[key]
        return _copy_state(state)

    def shadow_snapshot(self) -> object:
        """The shadow filter's part of :meth:`snapshot` (None outside a shadow gap)."""
        return self._shadow.snapshot() if self._start is not None else None

    def restore(self, snapshot: object) -> None:
        """Continue from a :meth:`snapshot` of a monitor with the same configuration."""
        state: dict[str, object] = snapshot[0]  # type: ignore[index]
        shadow: KalmanSnapshot | None = snapshot[1]  # type: ignore[index]
        vars(self).update(_copy_state(state))
        if shadow is not None:
            self._shadow.restore(shadow)

    def _gap_start_mean(self) -> float:
        """The largest over the spans tested of the mean statistic T of the fixes before the
        last ``gap_end_window`` occlusions (:meth:`_test_gap_start`), NaN before the first."""
        means = [sum_mean(values) for span in range(len(self._gap_start_on))
                 if (values := _span_values(self._gap_start_statistic, span))]
        return max(means, default=math.nan)

    def report(self) -> MonitorReport:
        """What the monitor has found so far."""
        test = windowed_nis_test(list(self._nis), self.params.nis_probability)
        std_scale = self._std_scale()
        cause = suspected_cause(std_scale, test.consistent, nis_matching_scale(list(self._nis)),
                                np.array(list(self._accelerations)).reshape(-1, 3),
                                self._gravity, self.params)
        clock = self.clock_offset()
        if std_scale > self.params.cause_std_scale and self.clock_suspect:
            cause = CLOCK
        edge = self._edge_variance()
        if cause == CONSISTENT and edge > 0:
            cause = EDGES  # the shadow gaps agree with the model, the real gaps' ends do not
        if cause in (CONSISTENT, IMU_NOISE) and test.consistent and self._block_scale() > 0:
            cause = CORRELATED  # each fix's NIS passes, the sums over blocks of them do not
        return MonitorReport(nis=test, shadow_gaps=self._innovation_scales.gaps,
                             variance_scale=self._scales.variance_scales(), std_scale=std_scale,
                             bridging_allowed=self.bridging_allowed, suspected_cause=cause,
                             clock_offset_s=math.nan if clock is None else clock[0],
                             clock_offset_std_s=math.nan if clock is None else clock[1],
                             steps=self._step_count, edge_offset_std_m=math.sqrt(edge),
                             gap_start_statistic=self._gap_start_mean(),
                             impact_variance_scale=self._impact_scales.variance_scales())


def _span_values(kept: deque[tuple[float, ...]], span: int) -> list[float]:
    """The values of span ``span`` in ``kept`` (one tuple per occlusion, one value per span
    tested: :meth:`ConsistencyMonitor._test_gap_start`), oldest first, without the NaN of
    occlusions whose run was too short for it."""
    return [values[span] for values in kept if not math.isnan(values[span])]


_NO_Y: Final = np.zeros(3)
_NO_S: Final = np.zeros((3, 3))
"""An empty block's sums of y (3,) m and S (3, 3) m^2 (read only, shared)."""
for _array in (_NO_Y, _NO_S):
    _array.flags.writeable = False

_NOT_STATE: Final = ("_shadow", "params", "_gravity")
"""ConsistencyMonitor attributes that are configuration, not state (left out of snapshots)."""


def _copy_state(state: dict[str, object]) -> dict[str, object]:
    """A copy of the monitor's state dict that shares nothing mutable with it: deques and lists
    are copied; floats, tuples, the arrays the monitor stores (each built new and never changed
    in place), the values it derives from them (cached, replaced, never changed in place) and
    the :class:`HorizonScales` (replaced by a changed copy, never changed in place:
    :meth:`ConsistencyMonitor._close`) are shared. It stands for ``copy.deepcopy``,
    which took about 0.7 ms per snapshot (the Tracker takes one at mocap rate); copying the
    scales' rows too took most of the 10-20 µs a snapshot still cost."""
    copied = state.copy()
    for key, value in state.items():
        if isinstance(value, list):
            copied[key] = list(value)
        elif isinstance(value, deque):
            copied[key] = deque(value, maxlen=value.maxlen)
    return copied
