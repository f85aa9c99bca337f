"""The compiled engine (:mod:`kfusion.kalman.compiled`) against the filterpy engine
(:class:`kfusion.kalman.KalmanFusion`): the same rows within 1e-9 m, the same outcomes, statuses
and counters, on simulated recordings that exercise every branch (gaps, a bad fix, re-acquisition,
lever-arm states, resets, a 10 s silence, pauses long enough to forget the state, saturation,
rejected samples, latency and a clock offset) and on the bundled BROAD excerpt. Plus one predict
and one update step checked against hand-derived values.

The kernels compile once per process (numba ``cache=True`` keeps the machine code on disk)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from kfusion.datasets import broad_excerpt
from kfusion.kalman import run_filter, run_smoother
from kfusion.monitor import MonitorParameters
from kfusion.recording import ImuSamples, MocapFrames, Recording, read_recording
from kfusion.simulate import OcclusionSpec, simulate

compiled = pytest.importorskip("kfusion.kalman.compiled")

TOLERANCE_M = 1e-9


def simulated(**changes: object) -> Recording:
    """A 6 s simulated arm lift with 0.15-0.6 s gaps."""
    simulation = simulate("arm_lift", seed=5, duration=6.0,
                          occlusions=OcclusionSpec(gap_range=(0.15, 0.6), spacing=1.0))
    recording = simulation.recording
    return dataclasses.replace(recording, info=dataclasses.replace(recording.info, **changes))


def with_mocap(recording: Recording, position: np.ndarray, quaternion: np.ndarray | None = None,
               t: np.ndarray | None = None) -> Recording:
    mocap = recording.mocap
    return dataclasses.replace(recording, mocap=MocapFrames(
        t=mocap.t if t is None else t, position=position,
        quaternion=mocap.quaternion if quaternion is None else quaternion))


def with_imu(recording: Recording, accelerometer: np.ndarray) -> Recording:
    imu = recording.imu
    return dataclasses.replace(recording, imu=ImuSamples(t=imu.t, accelerometer=accelerometer,
                                                         gyroscope=imu.gyroscope))


def bad_fix() -> Recording:
    """A 5 cm jump in one visible frame (gated), and a long gap ending far from the prediction
    (re-acquired after max_bridge_s)."""
    recording = simulated()
    position = recording.mocap.position.copy()
    visible = np.flatnonzero(np.isfinite(position[:, 0]))
    position[visible[100]] += 0.05
    position[visible[300]:visible[300] + 150] = np.nan  # 1.5 s gap: lost, then re-acquired
    position[visible[300] + 150:] += 0.03
    return with_mocap(recording, position)


def corrupt_imu() -> Recording:
    """NaN and implausible IMU samples (rejected), and saturation at a low range."""
    recording = simulated()
    accelerometer = recording.imu.accelerometer.copy()
    accelerometer[50] = np.nan
    accelerometer[400] = 1e7
    return with_imu(recording, accelerometer)


def knocked() -> Recording:
    """Knocks on the IMU every 0.35 s or so (:func:`kfusion.simulate.faults.imu_knocks`):
    impacts (``last_impact_t``) in gaps and before fixes, so the monitor keeps two classes of
    shadow-gap rows."""
    from kfusion.simulate import faults

    streams = faults.imu_knocks(faults.Streams.of(simulated()), every_s=0.35, amplitude=150.0,
                                frequency=120.0)
    return streams.recording


def reset_recording() -> Recording:
    """A mocap frame 1e120 s after the rest: the no-IMU propagation overflows (a reset), and
    the next frame initialises again."""
    recording = simulated()
    mocap = recording.mocap
    keep = len(mocap.t) // 2
    t = np.concatenate([mocap.t[:keep], [1e120, 2e120]])
    seen = np.flatnonzero(mocap.visible)[:2]  # two visible frames for the late rows
    position = np.concatenate([mocap.position[:keep], mocap.position[seen]])
    quaternion = np.concatenate([mocap.quaternion[:keep], mocap.quaternion[seen]])
    return with_mocap(recording, position, quaternion, t)


def clipped_below_range() -> Recording:
    """A fast reach whose gyroscope clips at 3 rad/s, far below the profile's 1000 dps: the
    plateau test (:func:`kfusion.kalman.model.plateau_step`) saturates its samples."""
    from kfusion.simulate import faults

    reach = simulate("random_reach", seed=1, duration=6.0,
                     occlusions=OcclusionSpec(gap_range=(0.15, 0.6), spacing=1.0)).recording
    return faults.imu_clips(faults.Streams.of(reach), gyroscope_range=3.0).recording


def paused(seconds: float) -> Recording:
    """Both streams silent for ``seconds`` half way (a capture paused, or a subject out of
    the volume with the IMU unplugged)."""
    recording = simulated()
    mocap, imu = recording.mocap, recording.imu
    half = mocap.t[len(mocap.t) // 2]
    mocap_t = np.where(mocap.t >= half, mocap.t + seconds, mocap.t)
    imu_t = np.where(imu.t >= half, imu.t + seconds, imu.t)
    return dataclasses.replace(
        with_mocap(recording, mocap.position, t=mocap_t),
        imu=ImuSamples(t=imu_t, accelerometer=imu.accelerometer, gyroscope=imu.gyroscope))


def long_silence() -> Recording:
    """A 10 s pause (:func:`paused`): the first fix after it lands on a prior about 10^12
    times looser than the mocap noise (position std 0.55 km, under
    :data:`kfusion.kalman.model.FORGOTTEN_POSITION_STD`), where an update that is not in
    Joseph order loses the posterior covariance to rounding."""
    return paused(10.0)


def forgotten_silence() -> Recording:
    """Pauses of 500 s and 1e7 s (a capture left paused overnight, and far longer): the no-IMU
    prediction passes :data:`kfusion.kalman.model.FORGOTTEN_POSITION_STD` and the state is
    forgotten (a reset) before the fix, which initialises it again. Fused instead, the fix
    after 1e7 s parted the engines by 4e-6 m."""
    recording = paused(500.0)
    mocap, imu = recording.mocap, recording.imu
    late = mocap.t[3 * len(mocap.t) // 4]
    mocap_t = np.where(mocap.t >= late, mocap.t + 1e7, mocap.t)
    imu_t = np.where(imu.t >= late, imu.t + 1e7, imu.t)
    return dataclasses.replace(
        with_mocap(recording, mocap.position, t=mocap_t),
        imu=ImuSamples(t=imu_t, accelerometer=imu.accelerometer, gyroscope=imu.gyroscope))


CASES = {
    # lever_arm None: the filter estimates it (12 states); the simulator declares it (0, 0, 0)
    "gaps_lever_arm_states": (lambda: simulated(lever_arm=None), {}),
    "given_lever_arm": (lambda: simulated(lever_arm=(0.01, -0.02, 0.015)), {}),
    "no_lever_arm": (simulated, {"lever_arm_std": 0.0}),
    "gated_and_reacquired": (bad_fix, {}),
    "rejected_and_saturated": (corrupt_imu, {"accelerometer_range": 12.0,
                                             "gyroscope_range": 0.05}),
    "reset": (reset_recording, {}),
    "latency_and_clock": (lambda: simulated(imu_time_offset=0.002, imu_clock_drift_ppm=40.0),
                          {"imu_latency_s": 0.007}),
    "scale_errors_no_gating": (simulated, {"accelerometer_scale_error": 0.01,
                                           "gyroscope_scale_error": 0.01,
                                           "gate_probability": None}),
    "broad_excerpt": (lambda: read_recording(broad_excerpt()), {}),
    "knocks": (knocked, {}),
    "long_silence": (long_silence, {}),
    "forgotten_silence": (forgotten_silence, {}),
    "clipped_below_range": (clipped_below_range, {}),
}


NIS_RTOL = {"long_silence": 1e-7}
"""The NIS's relative tolerance where it is looser than 1e-9: after a long silence the first
fixes cut the velocity variance by 1e9 or more (from 4.5e5 to about 5e-4 m^2/s^2 after 500 s),
so the two engines' rounding orders (full products, sparse sums) part at eps times that ratio
(after 500 s: 2e-8 measured on the NIS, 2e-9 on the velocity's std, 2e-12 m on the
positions)."""


@pytest.mark.parametrize("case", list(CASES))
def test_compiled_equals_filterpy(case: str) -> None:
    build, overrides = CASES[case]
    recording = build()
    fast = run_filter(recording, monitor=None, engine="compiled", **overrides)
    reference = run_filter(recording, monitor=None, engine="filterpy", **overrides)
    assert fast.outcome.tolist() == reference.outcome.tolist()
    assert fast.result.status.tolist() == reference.result.status.tolist()
    assert fast.counters == reference.counters
    np.testing.assert_allclose(fast.result.position, reference.result.position, rtol=0,
                               atol=TOLERANCE_M)
    np.testing.assert_allclose(fast.result.std, reference.result.std, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(fast.nis, reference.nis, rtol=NIS_RTOL.get(case, 1e-9))


def test_cases_exercise_their_branches() -> None:
    """The recordings above do reach the branches they are named for (else the equality
    would prove nothing)."""
    counters = {case: run_filter(build(), monitor=None, engine="compiled", **overrides).counters
                for case, (build, overrides) in CASES.items()}
    assert counters["gated_and_reacquired"]["gated"] >= 1
    assert counters["gated_and_reacquired"]["reacquired"] >= 1
    assert counters["rejected_and_saturated"]["imu_rejected"] == 2
    assert counters["rejected_and_saturated"]["accelerometer_saturated"] > 0
    assert counters["rejected_and_saturated"]["gyroscope_saturated"] > 0
    assert counters["reset"]["resets"] >= 1
    assert counters["reset"]["initialised"] >= 2  # re-initialised after each reset
    assert counters["gaps_lever_arm_states"]["occluded"] > 0
    assert run_filter(CASES["gaps_lever_arm_states"][0](), monitor=None).x.shape[1] == 12
    assert counters["long_silence"]["reacquired"] >= 1
    assert counters["long_silence"]["resets"] == 0  # fused after the silence, not reset
    assert counters["forgotten_silence"]["resets"] == 2  # forgotten in each pause
    assert counters["forgotten_silence"]["initialised"] == 3
    assert counters["clipped_below_range"]["gyroscope_saturated"] >= 100
    recording, overrides = knocked(), MONITOR_CASES["knocks_shrinking"][1]
    knocks = run_filter(recording, engine="compiled", **overrides)
    assert knocks.monitor is not None
    assert np.isfinite(knocks.monitor.impact_variance_scale).any()
    assert np.isfinite(knocks.monitor.variance_scale).any()  # both classes of shadow rows
    pooled = run_filter(recording, engine="compiled", impact_jerk=math.inf, **overrides)
    assert (knocks.variance_scale != pooled.variance_scale).any()  # the classes' scales differ


def test_unknown_engine_is_refused() -> None:
    with pytest.raises(ValueError, match=r"engine: expected one of \['compiled', 'filterpy'\]"):
        run_filter(simulated(), monitor=None, engine="fast")


def test_one_predict_step_by_hand() -> None:
    """R0 = R1 = I, f0 = f1 = f, b = 0, g: ``p' = p + v dt + dt^2/2 (f + g)``,
    ``v' = v + dt (f + g)``; ``P' = F P F^T + Q`` with P = I gives
    ``P'_pp = 1 + dt^2 + dt^4/4 + Q_pp`` (the bias column is -dt^2/2 I)."""
    config = np.zeros(compiled.CONFIG_SIZE)
    config[compiled.C_POSITION], config[compiled.C_VELOCITY], config[compiled.C_BIAS] = 0, 3, 6
    config[compiled.C_ACC_DENSITY] = 0.1
    dt = 0.01
    F, B = compiled.interval_matrices(np.eye(3), np.eye(3), dt, 9, config)
    Q = compiled.process_noise(dt, 9, 0.0, 0.0, config)
    x = np.array([1.0, 2.0, 3.0, 0.5, -0.5, 0.0, 0.0, 0.0, 0.0])
    P = np.eye(9)
    f = np.array([0.0, 0.0, 9.81])
    g = np.array([0.0, 0.0, -9.81 + 2.0])
    compiled.covariance_predict(x, P, F, B, np.concatenate([f, f, g]), Q)
    acceleration = f + g
    np.testing.assert_allclose(x[0:3], [1.0 + 0.5 * dt, 2.0 - 0.5 * dt,
                                        3.0 + 0.5 * dt * dt * acceleration[2]], atol=1e-15)
    np.testing.assert_allclose(x[3:6], [0.5, -0.5, dt * acceleration[2]], atol=1e-15)
    assert P[0, 0] == pytest.approx(1.0 + dt ** 2 + dt ** 4 / 4 + 0.01 * dt ** 3, rel=1e-14)
    assert P[0, 3] == pytest.approx(dt + dt ** 3 / 2 + 0.01 * dt ** 2, rel=1e-14)
    assert P[3, 3] == pytest.approx(1.0 + dt ** 2 + 0.01 * dt, rel=1e-14)


def test_one_update_step_by_hand() -> None:
    """P = s I, H = [I 0 0], R = r I: ``K = s / (s + r)`` on the position,
    ``p' = p + K (z - p)``, ``P'_pp = s r / (s + r)``, velocity untouched."""
    s, r = 4e-4, 1e-4
    x = np.zeros(9)
    P = np.eye(9) * s
    H = np.zeros((3, 9))
    H[:, 0:3] = np.eye(3)
    z = np.array([0.01, -0.02, 0.005])
    compiled.covariance_update(x, P, z, H, np.eye(3) * r)
    gain = s / (s + r)
    np.testing.assert_allclose(x[0:3], gain * z, rtol=1e-14)
    np.testing.assert_allclose(x[3:9], 0.0, atol=0)
    np.testing.assert_allclose(np.diag(P)[0:3], s * r / (s + r), rtol=1e-13)
    np.testing.assert_allclose(np.diag(P)[3:9], s, rtol=1e-14)


@pytest.mark.parametrize("case", ["gated_and_reacquired", "reset", "latency_and_clock",
                                  "given_lever_arm", "broad_excerpt"])
def test_compiled_smoother_equals_filterpy(case: str) -> None:
    """Forward kernel with the smoother's per-row predictions and transitions, and the njit
    RTS backward pass, against KalmanFusion and the numpy backward pass."""
    from kfusion.kalman import run_smoother

    build, overrides = CASES[case]
    recording = build()
    fast = run_smoother(recording, monitor=None, engine="compiled", **overrides)
    reference = run_smoother(recording, monitor=None, engine="filterpy", **overrides)
    assert fast.outcome.tolist() == reference.outcome.tolist()
    assert fast.result.status.tolist() == reference.result.status.tolist()
    np.testing.assert_allclose(fast.result.position, reference.result.position, rtol=0,
                               atol=TOLERANCE_M)
    np.testing.assert_allclose(fast.result.std, reference.result.std, rtol=1e-7, atol=1e-12)


def tracker_rows(recording: Recording, engine: str, **overrides: float
                 ) -> tuple[np.ndarray, list[str]]:
    """Feed a Tracker (``engine``) every event in the fusion order and read it at each mocap
    row: positions (m, 3) (NaN where it gives none) and statuses."""
    from kfusion.kalman import KalmanParameters
    from kfusion.kalman.events import merge_events
    from kfusion.tracker import Tracker

    info = recording.info
    params = KalmanParameters.from_profiles(info.imu, None, **overrides)
    tracker = Tracker(info.imu_to_body, info.gravity, params=params, lever_arm=info.lever_arm,
                      engine=engine)
    imu, mocap = recording.imu, recording.mocap
    positions = np.full((len(mocap.t), 3), np.nan)
    statuses = []
    for t, stream, row in merge_events(imu.t.tolist(), mocap.t.tolist(),
                                       params.imu_latency_s):
        if stream == 0:
            tracker.push_imu(imu.t[row], imu.accelerometer[row], imu.gyroscope[row])
            continue
        visible = bool(mocap.visible[row])
        tracker.push_mocap(t, mocap.position[row] if visible else None,
                           mocap.quaternion[row] if visible else None)
        estimate = tracker.estimate(t)
        positions[row] = estimate.position
        statuses.append(estimate.status)
    return positions, statuses


@pytest.mark.parametrize("case", ["gated_and_reacquired", "given_lever_arm", "broad_excerpt"])
def test_tracker_compiled_equals_filterpy(case: str) -> None:
    """CompiledFusion step by step (and as the consistency monitor's shadow filter) inside the
    Tracker gives the rows of KalmanFusion."""
    build, overrides = CASES[case]
    recording = build()
    fast_position, fast_status = tracker_rows(recording, "compiled", **overrides)
    position, status = tracker_rows(recording, "filterpy", **overrides)
    assert fast_status == status
    np.testing.assert_allclose(fast_position, position, rtol=0, atol=TOLERANCE_M)


@pytest.mark.parametrize("case", ["gated_and_reacquired", "broad_excerpt"])
def test_compiled_with_the_monitor_equals_filterpy(case: str) -> None:
    """With the consistency monitor (the default of ``kfusion track``) the compiled engine runs
    step by step (CompiledFusion, also as the monitor's shadow filter): the same rows."""
    build, overrides = CASES[case]
    recording = build()
    fast = run_filter(recording, engine="compiled", **overrides)
    reference = run_filter(recording, engine="filterpy", **overrides)
    assert fast.outcome.tolist() == reference.outcome.tolist()
    assert fast.result.status.tolist() == reference.result.status.tolist()
    np.testing.assert_allclose(fast.result.position, reference.result.position, rtol=0,
                               atol=TOLERANCE_M)
    np.testing.assert_allclose(fast.result.std, reference.result.std, rtol=1e-7, atol=1e-12)


def test_track_command_engines_agree(tmp_path: Path) -> None:
    """``kfusion track --engine compiled`` and ``--engine filterpy`` write the same rows."""
    from kfusion.cli import main
    from kfusion.track_file import read_track

    folder = broad_excerpt()
    outputs = {}
    for engine in ("compiled", "filterpy"):
        out = tmp_path / f"{engine}.csv"
        assert main(["track", str(folder), "--engine", engine, "--out", str(out)]) == 0
        outputs[engine] = read_track(out)
    np.testing.assert_allclose(outputs["compiled"].position, outputs["filterpy"].position,
                               rtol=0, atol=TOLERANCE_M)
    assert outputs["compiled"].status.tolist() == outputs["filterpy"].status.tolist()


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return compiled.rotation_matrix(q / np.linalg.norm(q))


@pytest.mark.parametrize("size", [9, 12])
def test_structured_predict_equals_the_general_product(size: int) -> None:
    """The hot-path predict (F from its blocks, no matrices formed) gives the bits of
    ``covariance_predict`` with :func:`interval_matrices` and :func:`process_noise`, and the
    transition product the smoother keeps (packed) those of ``F Phi``."""
    rng = np.random.default_rng(3)
    config = np.zeros(compiled.CONFIG_SIZE)
    config[compiled.C_POSITION], config[compiled.C_VELOCITY], config[compiled.C_BIAS] = 0, 3, 6
    config[compiled.C_ACC_DENSITY], config[compiled.C_ACC_WALK] = 0.02, 1e-3
    config[compiled.C_GRAVITY:compiled.C_GRAVITY + 3] = [0.0, 0.0, -9.81]
    for _ in range(20):
        R0, R1 = random_rotation(rng), random_rotation(rng)
        dt = float(rng.uniform(1e-3, 0.05))
        f0, f1 = rng.normal(size=3) * 5, rng.normal(size=3) * 5
        A = rng.normal(size=(size, size))
        P = A @ A.T
        x = rng.normal(size=size)
        extra, bias_variance = float(rng.uniform(0, 1e-3)), float(rng.uniform(0, 1e-6))
        F, B = compiled.interval_matrices(R0, R1, dt, size, config)
        Q = compiled.process_noise(dt, size, extra, bias_variance, config)
        x_general, P_general = x.copy(), P.copy()
        compiled.covariance_predict(x_general, P_general, F, B,
                                    np.concatenate([f0, f1, config[35:38]]), Q)
        blocks = np.empty((2, 3, 3))
        compiled.imu_blocks(R0, R1, dt, blocks)
        control = np.empty(size)
        compiled.control_term(R0, R1, dt, f0, f1, config, control)
        pp, pv, vv, bb = compiled.noise_terms(dt, extra, bias_variance, config)
        interval = rng.normal(size=compiled.TRANSITION_SIZE)  # a product Phi, packed
        expected_interval = compiled.matmul(F, whole_transition(interval, size))
        compiled.structured_predict(x, P, dt, blocks, control, pp, pv, vv, bb, config,
                                    np.empty((2, size, size)), interval)
        np.testing.assert_array_equal(x, x_general)
        np.testing.assert_array_equal(P, P_general)
        np.testing.assert_array_equal(whole_transition(interval, size), expected_interval)


def whole_transition(packed: np.ndarray, size: int) -> np.ndarray:
    """The (n, n) transition product of its packed form (TRANSITION_SIZE,): T, F_pb, F_vb
    row-major, on the layout's first 9 states (``unpack_prediction``'s transition)."""
    config = layout_config(size)
    P, transition = np.empty((size, size)), np.empty((size, size))
    compiled.unpack_prediction(np.zeros(compiled.triangle_size(size)), packed, config, P,
                               transition)
    return transition


@pytest.mark.parametrize("size", [9, 12])
@pytest.mark.parametrize("r", [1e-6, 1e-12])
def test_position_update_equals_the_joseph_form(size: int, r: float) -> None:
    """The hot-path update (adjugate 3x3 inverse; the Joseph form expanded with R = 1e-6 m^2,
    in filterpy's order with 1e-12, where S is up to 1e8 R: compiled.LOOSE_PRIOR) against
    ``covariance_update`` (the Joseph form with a LAPACK inverse), lever-arm columns in H."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        A = rng.normal(size=(size, size)) * 0.01
        P = A @ A.T + np.eye(size) * 1e-6
        x = rng.normal(size=size)
        H = np.zeros((3, size))
        H[:, 0:3] = np.eye(3)
        if size == 12:
            H[:, 9:12] = -random_rotation(rng)
        z = H @ x + rng.normal(size=3) * 0.01
        x_general, P_general = x.copy(), P.copy()
        compiled.covariance_update(x_general, P_general, z, H, np.eye(3) * r)
        PHT, S, S_inverse = np.empty((size, 3)), np.empty((3, 3)), np.empty((3, 3))
        compiled.innovation_covariance(P, H, r, PHT, S)
        compiled.inverse3(S, S_inverse)
        np.testing.assert_allclose(S_inverse @ S, np.eye(3), atol=1e-12)
        assert (np.diag(S).max() > compiled.LOOSE_PRIOR * r) == (r < 1e-6)
        compiled.position_update(x, P, z - H @ x, S_inverse, S, H, r, PHT,
                                 np.empty((size, 3)), np.empty((size, size)), 0,
                                 9 if size == 12 else -1)
        np.testing.assert_allclose(x, x_general, rtol=0, atol=1e-13)
        np.testing.assert_allclose(P, P_general, rtol=1e-9, atol=1e-18)
        np.testing.assert_array_equal(P, P.T)


def exact_update_covariance(P: np.ndarray, H: np.ndarray, noise_variance: float
                            ) -> np.ndarray:
    """``P - P H^T (H P H^T + R)^-1 H P`` in exact rational arithmetic (fractions), rounded to
    floats once at the end: the reference for a prior too loose for any float form."""
    from fractions import Fraction

    n = len(P)
    P_ = [[Fraction(float(value)) for value in row] for row in P]
    H_ = [[Fraction(float(value)) for value in row] for row in H]
    PHT = [[sum(P_[i][k] * H_[j][k] for k in range(n)) for j in range(3)] for i in range(n)]
    S = [[sum(H_[i][k] * PHT[k][j] for k in range(n)) + (Fraction(noise_variance) if i == j
                                                         else 0) for j in range(3)]
         for i in range(3)]
    # S^-1 by its adjugate (3 x 3)
    cofactor = [[S[(j + 1) % 3][(i + 1) % 3] * S[(j + 2) % 3][(i + 2) % 3]
                 - S[(j + 1) % 3][(i + 2) % 3] * S[(j + 2) % 3][(i + 1) % 3] for j in range(3)]
                for i in range(3)]
    determinant = sum(S[0][k] * cofactor[k][0] for k in range(3))
    K = [[sum(PHT[i][k] * cofactor[k][j] for k in range(3)) / determinant for j in range(3)]
         for i in range(n)]
    return np.array([[float(P_[i][j] - sum(K[i][k] * PHT[j][k] for k in range(3)))
                      for j in range(n)] for i in range(n)])


@pytest.mark.parametrize("size", [9, 12])
def test_a_fix_on_a_far_looser_prior_keeps_the_posterior(size: int) -> None:
    """A fix on a prior position variance 4e11 times R (500 s without data, a prior the filter
    now forgets first: :data:`kfusion.kalman.model.FORGOTTEN_POSITION_STD`). The update in
    filterpy's Joseph order gives the exact posterior (rational arithmetic) to 1e-6; expanded,
    its position block was off by eps |P| (2e-6 m^2 against 9e-8), 5x the whole answer."""
    rng = np.random.default_rng(7)
    factor = rng.normal(size=(size, size))
    P = factor @ factor.T * 1e-6
    block = np.array([[3.75e10, 1.3e8], [1.3e8, 4.5e5]])  # position, velocity of one axis
    for axis in range(3):
        index = [axis, 3 + axis]
        P[np.ix_(index, index)] += block * (1.0 + 0.1 * axis)
    H = np.zeros((3, size))
    H[:, 0:3] = np.eye(3)
    if size == 12:
        H[:, 9:12] = -random_rotation(rng)
    noise_variance = 9e-8
    exact = exact_update_covariance(P, H, noise_variance)
    x = np.zeros(size)
    PHT, S, S_inverse = np.empty((size, 3)), np.empty((3, 3)), np.empty((3, 3))
    compiled.innovation_covariance(P, H, noise_variance, PHT, S)
    compiled.inverse3(S, S_inverse)
    updated = P.copy()
    compiled.position_update(x, updated, np.zeros(3), S_inverse, S, H, noise_variance, PHT,
                             np.empty((size, 3)), np.empty((size, size)), 0,
                             9 if size == 12 else -1)
    output = H @ updated @ H.T
    np.testing.assert_allclose(output, H @ exact @ H.T, rtol=1e-6, atol=1e-15)
    assert np.diag(output) == pytest.approx([noise_variance] * 3, rel=1e-6)
    np.testing.assert_allclose(np.diag(updated), np.diag(exact), rtol=1e-6)


def layout_config(size: int) -> np.ndarray:
    """A kernel config holding only the state layout of ``size`` states (9 or 12)."""
    from kfusion.kalman.layout import layout_for

    layout = layout_for(size == 12)
    config = np.zeros(compiled.CONFIG_SIZE)
    config[[compiled.C_POSITION, compiled.C_VELOCITY, compiled.C_BIAS]] = (
        layout.start("position"), layout.start("velocity"), layout.start("bias"))
    return config


def imu_blocks(dt: float, rng: np.random.Generator) -> np.ndarray:
    """Random bias blocks (2, 3, 3) of an IMU transition: F_pb and F_vb of the sizes of dt^2
    and dt (:func:`kfusion.kalman.compiled.imu_blocks`' form)."""
    return np.stack([rng.normal(size=(3, 3)) * dt * dt, rng.normal(size=(3, 3)) * dt])


def imu_transition(size: int, dt: float, blocks: np.ndarray) -> np.ndarray:
    """``I + [[0, dt I, F_pb], [0, 0, F_vb], 0]`` (n, n) on the layout's first 9 states
    (:func:`kfusion.kalman.compiled.interval_matrices`' form), ``blocks`` from
    :func:`imu_blocks`."""
    F = np.eye(size)
    F[0:3, 3:6] = dt * np.eye(3)
    F[0:3, 6:9] = blocks[0]
    F[3:6, 6:9] = blocks[1]
    return F


def transition_product(size: int, steps: list[tuple[float, np.ndarray]]
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The product of the IMU transitions of ``steps`` ((dt s, blocks) in time order) as the
    whole (n, n) matrix, each step applied by the kernel's ``transition_times``, and as the
    kernel keeps it (``accumulate_transition``'s packed form, from the identity's)."""
    config = layout_config(size)
    whole = np.eye(size)
    packed = np.zeros(compiled.TRANSITION_SIZE)
    for dt, blocks in steps:
        before = whole.copy()
        compiled.transition_times(before, whole, dt, blocks, config)
        compiled.accumulate_transition(packed, dt, blocks)
    return whole, packed


@pytest.mark.parametrize("size", [9, 12])
def test_rts_row_equals_the_numpy_step(size: int) -> None:
    """The compiled RTS step (allocation-free, its own Gaussian elimination, the prediction
    packed) against ``smoother.rts_step`` (numpy's solve and products), on covariances spanning
    12 decades (position to bias), and against ``np.linalg.solve`` for the elimination
    itself."""
    from kfusion.kalman.smoother import rts_step

    rng = np.random.default_rng(7)
    scales = np.geomspace(1e-6, 1.0, size)
    work = np.empty((7, size, size))
    config = layout_config(size)
    packed_x = np.empty((1, size))
    packed_P = np.empty((1, compiled.triangle_size(size)))
    packed_transition = np.empty((1, compiled.TRANSITION_SIZE))
    for _ in range(20):
        A = rng.normal(size=(4, size, size)) * scales[:, None]
        P = A @ A.transpose(0, 2, 1) + np.eye(size) * 1e-14
        P = 0.5 * (P + P.transpose(0, 2, 1))
        x = rng.normal(size=(3, size))
        transition, packed = transition_product(size, [(0.005, imu_blocks(0.005, rng)),
                                                       (0.01, imu_blocks(0.01, rng))])
        expected_x, expected_P = rts_step(x[0], P[0], x[2], P[2], transition, x[1], P[1])
        rows_x, rows_P = x[:2].copy(), P[:2].copy()
        assert compiled.pack_prediction(x[2], P[2], packed, packed_x[0], packed_P[0],
                                        packed_transition[0])
        compiled.rts_row(rows_x, rows_P, 0, packed_x, packed_P, packed_transition, 0, config,
                         work)
        np.testing.assert_allclose(rows_x[0], expected_x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(rows_P[0], expected_P, rtol=1e-6,
                                   atol=1e-9 * np.abs(expected_P).max())
        np.testing.assert_array_equal(rows_P[0], rows_P[0].T)
        np.testing.assert_array_equal(rows_x[1], x[1])  # row k + 1 is only read
        out = np.empty((size, 3))
        right = rng.normal(size=(size, 3))
        assert compiled.solve_into(P[2], right, out, np.empty((size, size)))
        # backward stable: the residual is a few rounding errors of |P| |out|
        residual = np.abs(P[2] @ out - right).max()
        assert residual <= 1e-14 * size * np.abs(P[2]).max() * np.abs(out).max()
    singular = np.zeros((size, size))
    assert not compiled.solve_into(singular, np.ones((size, 1)), np.empty((size, 1)),
                                   np.empty((size, size)))


def test_status_codes_follow_the_status_rule() -> None:
    """The compiled status loop against the rule row by row, thresholds hit exactly."""
    from kfusion.kalman.batch import row_statuses

    rng = np.random.default_rng(5)
    since = np.concatenate([rng.uniform(0, 1.0, 300), [0.0, 0.3, np.inf, np.nan, 0.005]])
    since[::7] = 0.3  # max_bridge_s itself
    fused = rng.random(len(since)) < 0.5
    reckoned = rng.random(len(since)) < 0.8
    for dead_reckoned in (reckoned, None):
        np.testing.assert_array_equal(
            row_statuses(since, fused, 0.3, dead_reckoned, engine="compiled"),
            row_statuses(since, fused, 0.3, dead_reckoned))


@pytest.mark.parametrize("case", ["gaps_lever_arm_states", "gated_and_reacquired", "reset"])
def test_kept_and_recomputed_predictions_give_the_same_bits(case: str,
                                                             monkeypatch: pytest.MonkeyPatch
                                                             ) -> None:
    """The compiled backward pass reads each row's prediction as the forward kernel kept it
    (packed: P's upper triangle and the transition product's free entries), or, for a forward
    pass that kept only states every SAVE_EVERY rows, runs the forward loop again block by block
    to recompute them. Kept, recomputed in blocks of 7 rows (many boundaries, inside and across
    segments) and recomputed in one block give the same bits."""
    from kfusion.kalman import run_smoother
    from kfusion.kalman.batch import compiled_rows, make_fusion, resolve_parameters
    from kfusion.kalman.smoother import initialised_segments

    build, overrides = CASES[case]
    recording = build()
    kept = run_smoother(recording, monitor=None, engine="compiled", **overrides)
    assert np.isfinite(kept.x).any(axis=1).sum() > 100
    fusion = make_fusion(recording, resolve_parameters(recording, None, overrides))
    for save_every in (len(recording.mocap) + 1, 7):
        monkeypatch.setattr(compiled, "SAVE_EVERY", save_every)
        forward = compiled_rows(recording, fusion, smoothing=True)
        assert forward is not None and forward[1].replay is not None
        recorder, run = forward
        replay = run.replay.without_predictions()
        assert replay.predictions is None
        segments = initialised_segments(recorder.outcome.astype(str), recorder.initialised)
        compiled.smooth_in_place(replay, recorder.x, recorder.P, segments)
        np.testing.assert_array_equal(recorder.x, kept.x)
        np.testing.assert_array_equal(recorder.P, kept.P)


def test_a_prediction_packs_and_unpacks_to_the_same_bits() -> None:
    """The forward kernel keeps the product of a row's transitions in its 19 free entries
    (T, F_pb, F_vb: accumulate_transition), pack_prediction keeps those and P's upper
    triangle, and unpack_prediction rebuilds them. Here for products of hand-built IMU
    transitions and a no-IMU one (zero blocks) on the 12-state layout (lever-arm rows and
    columns are the identity's): the same bits as the whole (n, n) products the kernel's
    transition_times and matmul give, with T the sum of the steps' dt. An asymmetric P, or a
    product that is not finite, is refused (False, NaN time): the backward pass does not
    smooth across such a row."""
    from kfusion.kalman.layout import LEVER_LAYOUT

    n = LEVER_LAYOUT.size
    p, v = LEVER_LAYOUT.start("position"), LEVER_LAYOUT.start("velocity")
    config = layout_config(n)
    rng = np.random.default_rng(3)
    steps = [(0.004, imu_blocks(0.004, rng)), (0.005, imu_blocks(0.005, rng)),
             (0.02, np.zeros((2, 3, 3))), (0.003, imu_blocks(0.003, rng))]
    Phi, packed = transition_product(n, steps)
    by_matmul = np.eye(n)
    for dt, blocks in steps:
        by_matmul = compiled.matmul(imu_transition(n, dt, blocks), by_matmul)
    np.testing.assert_array_equal(Phi, by_matmul)
    A = rng.normal(size=(n, n))
    P = A @ A.T
    P = 0.5 * (P + P.T)
    x = rng.normal(size=n)
    out_x = np.empty(n)
    out_P = np.empty(compiled.triangle_size(n))
    out_transition = np.empty(compiled.TRANSITION_SIZE)
    assert compiled.pack_prediction(x, P, packed, out_x, out_P, out_transition)
    assert out_transition[0] == Phi[p, v] == ((0.004 + 0.005) + 0.02) + 0.003
    full_P, full_Phi = np.empty((n, n)), np.empty((n, n))
    compiled.unpack_prediction(out_P, out_transition, config, full_P, full_Phi)
    np.testing.assert_array_equal(out_x, x)
    np.testing.assert_array_equal(full_P, P)
    np.testing.assert_array_equal(full_Phi, Phi)
    lopsided = P.copy()
    lopsided[0, 1] += 1e-12
    assert not compiled.pack_prediction(x, lopsided, packed, out_x, out_P, out_transition)
    assert math.isnan(out_transition[0])
    for entry, value in ((0, math.nan), (5, math.inf), (18, -math.inf)):
        broken = packed.copy()
        broken[entry] = value
        assert not compiled.pack_prediction(x, P, broken, out_x, out_P, out_transition)
        assert math.isnan(out_transition[0])


def test_compiled_predict_checks_every_input_form() -> None:
    """CompiledFusion.predict's cheap path (float64 arrays, tuples and lists of floats) and its
    full checks (anything else) give KalmanFusion's outcomes, counters and errors."""
    from kfusion.kalman import KalmanFusion, KalmanParameters
    from kfusion.kalman.compiled_fusion import CompiledFusion

    params = KalmanParameters.from_profiles("mpu9255")
    engines = [engine((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, -9.81), params)
               for engine in (KalmanFusion, CompiledFusion)]
    samples = [(0.01, np.array([0.0, 0.0, 9.81]), (0.0, 0.0, 0.1)),
               (0.02, [0.0, 0.1, 9.8], np.array([0.0, 0.0, 0.1], dtype=np.float32)),
               (np.float64(0.03), (0.0, 0.1, 9.8), [0, 0, 1]),
               (0.04, (0.0, math.nan, 9.8), (0.0, 0.0, 0.1)),
               (0.04, (0.0, 0.1, 9.8), (0.0, 0.0, 0.1)),
               (0.04, (0.0, 0.1, 9.8), (0.0, 0.0, 0.1)),  # identical duplicate
               (0.05, np.array([0.0, 1e9, 9.8]), (0.0, 0.0, 0.1))]  # implausible
    for t, accelerometer, gyroscope in samples:
        outcomes = {engine.predict(t, accelerometer, gyroscope) for engine in engines}
        assert len(outcomes) == 1, (t, outcomes)
    for t, accelerometer, gyroscope, message in (
            (0.06, (0.0, 0.1), (0.0, 0.0, 0.1), r"accelerometer: expected shape \(3,\)"),
            (math.inf, (0.0, 0.1, 9.8), (0.0, 0.0, 0.1), "expected a finite time"),
            (0.035, (0.0, 0.1, 9.8), (0.0, 0.0, 0.1), "not after the previous IMU sample")):
        for engine in engines:
            with pytest.raises(ValueError, match=message):
                engine.predict(t, accelerometer, gyroscope)
    assert engines[0].counters == engines[1].counters


def assert_smoothers_agree(fast, reference) -> None:  # type: ignore[no-untyped-def]
    """Two SmootherRuns: the same outcomes and statuses, positions within 1e-9 m, filtered
    and smoothed."""
    assert fast.outcome.tolist() == reference.outcome.tolist()
    for mine, theirs in ((fast.result, reference.result), (fast.filtered, reference.filtered)):
        assert mine.status.tolist() == theirs.status.tolist()
        np.testing.assert_allclose(mine.position, theirs.position, rtol=0, atol=TOLERANCE_M)
        np.testing.assert_allclose(mine.std, theirs.std, rtol=1e-7, atol=1e-12)


@pytest.mark.parametrize(("case", "save_every"), [("gated_and_reacquired", 7),
                                                  ("gated_and_reacquired", 1024),
                                                  ("broad_excerpt", 1024)])
def test_compiled_smoother_with_the_monitor_equals_filterpy(case: str, save_every: int,
                                                            monkeypatch: pytest.MonkeyPatch
                                                            ) -> None:
    """With the consistency monitor (the default) the compiled smoother runs its forward pass
    step by step (CompiledFusion, saving packed states every SAVE_EVERY rows; 7: many block
    boundaries) and the compiled backward pass on them: the rows of KalmanFusion and the numpy
    backward pass."""
    from kfusion.kalman import run_smoother

    build, overrides = CASES[case]
    recording = build()
    monkeypatch.setattr(compiled, "SAVE_EVERY", save_every)
    fast = run_smoother(recording, engine="compiled", **overrides)
    reference = run_smoother(recording, engine="filterpy", **overrides)
    assert fast.monitor is not None and reference.monitor is not None
    assert_smoothers_agree(fast, reference)
    assert (fast.outcome == "gated").any() or case == "broad_excerpt"


@pytest.mark.broad
def test_compiled_smoother_with_the_monitor_equals_filterpy_on_a_broad_trial() -> None:
    """The same on 20 s of BROAD trial 21 with gaps cut into it."""
    from kfusion.config import first_seconds
    from kfusion.datasets import broad_trials
    from kfusion.evaluate import cut_gaps
    from kfusion.kalman import run_smoother
    from kfusion.readers.broad import read_broad

    path = next(path for path in broad_trials() if path.name.startswith("21"))
    recording = cut_gaps(first_seconds(read_broad(path, mocap_step=3), 20.0),
                         rng=np.random.default_rng(0), gap_range=(0.1, 0.3)).recording
    assert_smoothers_agree(run_smoother(recording, engine="compiled"),
                           run_smoother(recording, engine="filterpy"))


def test_predict_with_shadow_equals_two_predictions() -> None:
    """CompiledFusion.predict_valid_with (the filter and the monitor's shadow in one kernel
    call) leaves both states and counters bit-identical to two predict_valid calls, returns
    dead_reckoning_until() exactly, and refuses a shadow of another configuration. The
    shadow starts from the filter's snapshot after a fix (as the monitor's does) and the
    recording has saturated and implausible samples and gaps."""
    from kfusion.kalman import KalmanParameters
    from kfusion.kalman.compiled_fusion import CompiledFusion

    recording = corrupt_imu()
    info = recording.info
    params = KalmanParameters.from_profiles("mpu9255", accelerometer_range=12.0)
    paired, shadow, alone, alone_shadow = (
        CompiledFusion(info.imu_to_body, info.gravity, params) for _ in range(4))
    imu, mocap = recording.imu, recording.mocap
    frame = 0
    shadow_running = False
    for index, t in enumerate(imu.t.tolist()):
        while frame < len(mocap.t) and mocap.t[frame] < t:
            visible = bool(mocap.visible[frame])
            for fusion in (paired, alone):
                fusion.update(mocap.t[frame], mocap.position[frame] if visible else None,
                              mocap.quaternion[frame] if visible else None)
            if visible and frame % 40 == 0:  # a shadow gap starts from the filter's state
                shadow.restore(paired.snapshot())
                alone_shadow.restore(alone.snapshot())
                shadow_running = True
            frame += 1
        values = imu.accelerometer[index].tolist() + imu.gyroscope[index].tolist()
        if not all(map(math.isfinite, values)):
            continue  # the callers pass checked samples only
        horizon = paired.predict_valid_with(shadow if shadow_running else None, t, *values)
        alone.predict_valid(t, *values)
        if shadow_running:
            alone_shadow.predict_valid(t, *values)
        assert horizon == alone.dead_reckoning_until()
    assert alone.counters["imu_rejected"] == 1 and alone.counters["accelerometer_saturated"] > 0
    for mine, theirs in ((paired, alone), (shadow, alone_shadow)):
        assert np.array_equal(mine.snapshot().state, theirs.snapshot().state, equal_nan=True)
        assert mine.counters == theirs.counters
    other = CompiledFusion(info.imu_to_body, info.gravity, KalmanParameters.from_profiles("um7"))
    with pytest.raises(ValueError, match="shadow: expected a CompiledFusion built with the same"):
        paired.predict_valid_with(other, 100.0, 0.0, 0.0, 9.8, 0.0, 0.0, 0.0)


def broken_clock() -> Recording:
    """An undeclared 40 ms IMU clock offset: the monitor's shadow gaps refuse the model, fixes
    are gated (the monitor then reads the filter's estimate before each frame) and
    re-acquired."""
    recording = simulated()
    imu = recording.imu
    return dataclasses.replace(recording, imu=ImuSamples(
        t=imu.t + 0.04, accelerometer=imu.accelerometer, gyroscope=imu.gyroscope))


# "knocks_shrinking": scales below 1 after a few gaps (the defaults keep 1 for a recording this
# short), so the two classes of shadow rows give different bounds
MONITOR_CASES = {**CASES, "broken_clock": (broken_clock, {}),
                 "knocks_shrinking": (knocked, {"monitor": MonitorParameters(
                     minimum_shadow_gaps=2, matching_quantile=0.9)})}


@pytest.mark.parametrize("case", list(MONITOR_CASES))
def test_two_pass_monitor_equals_event_by_event(case: str) -> None:
    """With the consistency monitor, the compiled engine's two passes (the whole-loop kernel,
    then the monitor's bookkeeping: kfusion.kalman.monitored) give the bits of the
    event-by-event run (CompiledFusion for the filter and the shadow), the Tracker's."""
    build, overrides = MONITOR_CASES[case]
    recording = build()
    fast = run_filter(recording, engine="compiled", **overrides)
    reference = run_filter(recording, engine="compiled", stepwise=True, **overrides)
    for name in ("position", "std", "status", "time_since_fix"):
        np.testing.assert_array_equal(getattr(fast.result, name),
                                      getattr(reference.result, name), err_msg=name)
    for name in ("x", "P", "output_matrix", "output_offset", "outcome", "nis",
                 "variance_scale"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(reference, name),
                                      err_msg=name)
    assert fast.counters == reference.counters
    assert repr(fast.monitor) == repr(reference.monitor)  # NaN fields compare by text


def test_the_monitor_cases_reach_refusal_and_gated_fixes() -> None:
    run = run_filter(broken_clock(), engine="compiled")
    assert run.monitor is not None and not run.monitor.bridging_allowed
    assert run.counters["gated"] >= 1 and (run.result.status == "lost").any()


@pytest.mark.parametrize("case", ["broken_clock", "long_gaps", "broad_excerpt"])
def test_two_pass_smoother_forward_pass_equals_event_by_event(case: str) -> None:
    """The smoother's forward pass with the monitor in two passes gives the bits of the
    event-by-event one, and so does its backward pass from the states the two passes keep
    (``long_gaps``: 15 s at 100 Hz, more than SAVE_EVERY rows)."""
    if case == "long_gaps":
        recording = simulate("arm_lift", seed=8, duration=15.0,
                             occlusions=OcclusionSpec(gap_range=(0.15, 0.6),
                                                      spacing=1.0)).recording
        assert len(recording.mocap) > compiled.SAVE_EVERY
    else:
        recording = MONITOR_CASES[case][0]()
    fast = run_smoother(recording, engine="compiled")
    reference = run_smoother(recording, engine="compiled", stepwise=True)
    for result, expected in ((fast.result, reference.result),
                             (fast.filtered, reference.filtered)):
        for name in ("position", "std", "status", "time_since_fix"):
            np.testing.assert_array_equal(getattr(result, name), getattr(expected, name),
                                          err_msg=name)
    np.testing.assert_array_equal(fast.x, reference.x)
    np.testing.assert_array_equal(fast.P, reference.P)
    assert repr(fast.monitor) == repr(reference.monitor)


def test_a_frame_stamped_out_of_row_order_is_smoothed_without_writing_past_the_blocks(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """One mocap frame stamped 1000 s ahead (the reader refuses it; the API takes it) puts
    that row last among the merged events. The backward pass's blocks assume row k is the k-th
    frame event, and recomputing them wrote past the blocks' arrays: the default monitored
    smoother aborted the process with heap corruption (an adversarial review). Such a pass now
    recomputes in one block and gives the kept predictions' bits. ``run_smoother`` itself now
    refuses the recording, naming the row (:func:`kfusion.kalman.smoother.
    frames_in_time_order`): its backward pass paired that row with a prediction it was never
    the start of, and reported it ``tracked`` with a NaN std in both engines."""
    from kfusion.kalman.batch import compiled_rows, make_fusion, resolve_parameters
    from kfusion.kalman.smoother import initialised_segments
    from kfusion.simulate import faults

    base = simulate("arm_lift", seed=8, duration=8.0,
                    occlusions=OcclusionSpec(gap_range=(0.15, 0.6), spacing=1.0)).recording
    recording = faults.mocap_future_stamp(faults.Streams.of(base), fraction=0.4).recording
    monkeypatch.setattr(compiled, "SAVE_EVERY", 64)  # many blocks on 801 rows

    def forward() -> tuple[Any, Any, list[tuple[int, int]]]:
        rows = compiled_rows(recording, make_fusion(recording,
                                                    resolve_parameters(recording, None, {})),
                             smoothing=True)
        assert rows is not None and rows[1].replay is not None
        recorder, run = rows
        return recorder, run, initialised_segments(recorder.outcome.astype(str),
                                                   recorder.initialised)

    kept_recorder, kept_run, segments = forward()
    compiled.smooth_in_place(kept_run.replay, kept_recorder.x, kept_recorder.P, segments)
    recorder, run, _ = forward()
    compiled.smooth_in_place(run.replay.without_predictions(), recorder.x, recorder.P, segments)
    np.testing.assert_array_equal(recorder.x, kept_recorder.x)
    np.testing.assert_array_equal(recorder.P, kept_recorder.P)
    row = int(np.argmax(recording.mocap.t)) + 1
    for engine, monitor in (("compiled", None), ("compiled", MonitorParameters()),
                            ("filterpy", None)):
        with pytest.raises(ValueError, match=rf"^smoother: mocap\.t: row {row} \(.* s\) is "
                           rf"earlier than row {row - 1} \(1003\.2 s\); the smoother needs"):
            run_smoother(recording, engine=engine, monitor=monitor)
    filtered = run_filter(recording, engine="compiled")  # the filter fuses it in time order,
    assert filtered.outcome[row - 1] == "initialised"  # on a state forgotten over 1000 s


def test_one_shared_output_matrix_gives_the_bits_of_one_per_row() -> None:
    """Without the lever-arm states every row's H is [I 0 0], kept once (a read-only view,
    row stride 0: model.output_matrices). The covariances H P H^T (batch.position_covariances:
    P's position block where P is finite, else row by row), the compiled points
    (compiled.point_rows with one (1, 3, n) H) and row selections give the bits of the same H
    copied to every row; with a NaN row the covariances fall back to the products."""
    from kfusion.kalman.batch import position_covariances
    from kfusion.kalman.model import output_matrices, output_matrix_rows

    rng = np.random.default_rng(11)
    rows, n = 400, 9
    A = rng.normal(size=(rows, n, n)) * np.geomspace(1e-7, 1e2, n)
    P = A @ A.transpose(0, 2, 1)
    x = rng.normal(size=(rows, n))
    offset = rng.normal(size=(rows, 3)) * 0.05
    shared = output_matrices(rows, n, False)
    assert shared.strides[0] == 0 and not shared.flags.writeable
    per_row = np.array(shared)
    assert per_row.strides[0] != 0
    np.testing.assert_array_equal(per_row[:, :, 0:3], np.broadcast_to(np.eye(3), (rows, 3, 3)))
    np.testing.assert_array_equal(per_row[:, :, 3:], 0.0)
    for covariances in (P, np.where(np.arange(rows)[:, None, None] == 7, np.nan, P)):
        fast = position_covariances(covariances, shared)
        np.testing.assert_array_equal(fast, position_covariances(covariances, per_row))
        np.testing.assert_array_equal(np.signbit(fast),
                                      np.signbit(position_covariances(covariances, per_row)))
    position, variance = compiled.point_rows(np.array(shared[:1]), x, offset, P)
    expected_position, expected_variance = compiled.point_rows(per_row, x, offset, P)
    np.testing.assert_array_equal(position, expected_position)
    np.testing.assert_array_equal(variance, expected_variance)
    for count in (0, 2):  # neither one map per row nor one for all: refused, never read past
        with pytest.raises(ValueError, match="point_rows: expected one output map per row"):
            compiled.point_rows(np.array(per_row[:count]), x, offset, P)
    chosen = np.array([3, 3, 17, 399])
    selected = output_matrix_rows(shared, chosen)
    assert selected.strides[0] == 0
    np.testing.assert_array_equal(selected, per_row[chosen])
    varying = output_matrices(rows, 12, True)
    assert varying.flags.writeable and varying.shape == (rows, 3, 12) and not varying.any()
    np.testing.assert_array_equal(output_matrix_rows(varying, chosen), varying[chosen])


def test_the_compiled_plateau_test_equals_the_model_s() -> None:
    """compiled.plateau_level against model.plateau_step on quantised random walks that clip,
    each axis at its own level and one a bias apart on its two sides (both sensors' floors):
    the same tops, repeats and levels, sample by sample."""
    from kfusion.kalman import model

    rng = np.random.default_rng(4)
    for floor in (model.PLATEAU_FLOOR_ACCELEROMETER, model.PLATEAU_FLOOR_GYROSCOPE):
        high = floor * np.array([1.3, 1.25, 1.4])
        low = -high + np.array([0.0, 0.02 * floor, 0.0])
        walk = np.cumsum(rng.normal(scale=0.15 * floor, size=(3000, 3)), axis=0)
        samples = np.clip(np.round(walk / (0.01 * floor)) * 0.01 * floor, low, high)
        scalars = compiled.initial_scalars()
        tops, repeats = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        previous, saturated = None, 0
        for sample in samples:
            tops, repeats, level = model.plateau_step(sample, previous, tops, repeats, floor)
            found = compiled.plateau_level(sample, scalars, compiled.ACCELEROMETER,
                                           compiled.ACCELEROMETER_PLATEAU, floor)
            assert found == level
            state = scalars[compiled.ACCELEROMETER_PLATEAU:compiled.ACCELEROMETER_PLATEAU + 6]
            assert tuple(state) == tops + repeats
            scalars[compiled.ACCELEROMETER:compiled.ACCELEROMETER + 3] = sample
            previous, saturated = sample, saturated + (level > 0)
        assert saturated > 100  # the walk does clip
