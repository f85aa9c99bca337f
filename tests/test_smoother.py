"""The RTS smoother (kfusion.kalman.smoother): the backward pass with a control input against the
batch Gaussian posterior, filterpy's rts_smoother dropping B u, and gap filling."""

from __future__ import annotations

import dataclasses

import numpy as np
from filterpy.kalman import KalmanFilter

from kfusion.conventions import BRIDGED, LOST, TRACKED
from kfusion.evaluate import gap_errors, metrics_from_errors
from kfusion.kalman import GATED, run_filter, run_smoother, smooth_recording
from kfusion.kalman.smoother import initialised_segments, rts_backward, smoother_status
from kfusion.methods import track_with_method
from kfusion.recording import MocapFrames
from kfusion.simulate import OcclusionSpec, simulate


def random_linear_system(rng: np.random.Generator, steps: int = 12, size: int = 4):
    """x_{k+1} = F_k x_k + B_k u_k + w_k, z_k = H x_k + v_k with random F, B, u, Q."""
    F = [np.eye(size) + 0.1 * rng.normal(size=(size, size)) for _ in range(steps)]
    B = [rng.normal(size=(size, 2)) for _ in range(steps)]
    u = [rng.normal(size=2) for _ in range(steps)]
    Q = []
    for _ in range(steps):
        A = 0.1 * rng.normal(size=(size, size))
        Q.append(A @ A.T + 0.01 * np.eye(size))
    H = rng.normal(size=(2, size))
    R = 0.05 * np.eye(2)
    x0, P0 = rng.normal(size=size), np.eye(size)
    z = [rng.normal(size=2) for _ in range(steps)]
    return F, B, u, Q, H, R, x0, P0, z


def batch_posterior(F, B, u, Q, H, R, x0, P0, z):
    """Mean and covariance of all states x_1..x_n given z_1..z_n, from the joint Gaussian."""
    steps, size = len(F), len(x0)
    # x_k = A_k x0 + c_k + sum_j G_kj w_j: build the joint mean and covariance of (x_1..x_n)
    mean = np.zeros((steps, size))
    transfer = [np.eye(size)]  # transfer[k]: from x0 to x_k
    state = x0.copy()
    for k in range(steps):
        state = F[k] @ state + B[k] @ u[k]
        mean[k] = state
    noise_map = np.zeros((steps * size, (steps + 1) * size))  # columns: x0 deviation, w_1..w_n
    for k in range(steps):
        transfer.append(F[k] @ transfer[-1])
        noise_map[k * size:(k + 1) * size, :size] = transfer[k + 1]
        for j in range(k + 1):
            block = np.eye(size)
            for i in range(j + 1, k + 1):
                block = F[i] @ block
            noise_map[k * size:(k + 1) * size, (j + 1) * size:(j + 2) * size] = block
    sources = np.zeros(((steps + 1) * size, (steps + 1) * size))
    sources[:size, :size] = P0
    for j in range(steps):
        sources[(j + 1) * size:(j + 2) * size, (j + 1) * size:(j + 2) * size] = Q[j]
    covariance = noise_map @ sources @ noise_map.T
    H_all = np.kron(np.eye(steps), H)
    S = H_all @ covariance @ H_all.T + np.kron(np.eye(steps), R)
    gain = covariance @ H_all.T @ np.linalg.inv(S)
    innovation = np.concatenate(z) - H_all @ mean.ravel()
    posterior_mean = mean.ravel() + gain @ innovation
    posterior_covariance = covariance - gain @ S @ gain.T
    blocks = np.array([posterior_covariance[k * size:(k + 1) * size, k * size:(k + 1) * size]
                       for k in range(steps)])
    return posterior_mean.reshape(steps, size), blocks


def forward(F, B, u, Q, H, R, x0, P0, z):
    """filterpy forward pass keeping filtered and predicted states."""
    kf = KalmanFilter(dim_x=len(x0), dim_z=2, dim_u=2)
    kf.x, kf.P, kf.H, kf.R = x0.copy(), P0.copy(), H, R
    xf, Pf, xp, Pp = [], [], [], []
    for k in range(len(F)):
        kf.predict(u=u[k], B=B[k], F=F[k], Q=Q[k])
        xp.append(kf.x.copy())
        Pp.append(kf.P.copy())
        kf.update(z[k])
        xf.append(kf.x.copy())
        Pf.append(kf.P.copy())
    return np.array(xf), np.array(Pf), np.array(xp), np.array(Pp)


def test_backward_pass_with_control_input_equals_the_batch_posterior():
    rng = np.random.default_rng(7)
    system = random_linear_system(rng)
    F, B, u, Q, H, R, x0, P0, z = system
    xf, Pf, xp, Pp = forward(*system)
    # transitions[k] maps row k-1 to row k
    transitions = np.array([np.eye(len(x0))] + F[1:])
    x_smoothed, P_smoothed = rts_backward(xf, Pf, xp, Pp, transitions)
    mean, covariance = batch_posterior(*system)
    np.testing.assert_allclose(x_smoothed, mean, atol=1e-10)
    np.testing.assert_allclose(P_smoothed, covariance, atol=1e-10)


def test_filterpy_rts_smoother_drops_the_control_input():
    # the reason kfusion writes its own backward pass (filterpy issue #164)
    rng = np.random.default_rng(7)
    system = random_linear_system(rng)
    F, B, u, Q, H, R, x0, P0, z = system
    xf, Pf, _, _ = forward(*system)
    kf = KalmanFilter(dim_x=len(x0), dim_z=2)
    # filterpy uses Fs[k+1], Qs[k+1] from step k to k+1: the same F, Q as the forward pass
    x_filterpy, P_filterpy, _, _ = kf.rts_smoother(xf, Pf, Fs=F, Qs=Q)
    mean, covariance = batch_posterior(*system)
    # covariances do not depend on u and agree; the means are off by the dropped B u
    np.testing.assert_allclose(P_filterpy, covariance, atol=1e-10)
    assert np.abs(x_filterpy[:-1] - mean[:-1]).max() > 0.1


def test_backward_passes_restart_at_each_initialisation():
    # the filter forgot its state at row 4 (an overflow) and was re-initialised at row 6
    outcome = np.array(["occluded", "initialised", "accepted", "occluded", "occluded",
                        "occluded", "initialised", "accepted"])
    initialised = np.array([False, True, True, True, False, False, True, True])
    assert initialised_segments(outcome, initialised) == [(1, 4), (6, 8)]


def test_smoother_status():
    t = np.arange(12) * 0.1
    fixed = np.array([0, 0, 1, 1, 0, 0, 0, 0, 0, 1, 0, 0], dtype=bool)
    status = smoother_status(t, fixed, max_bridge_s=0.25)
    # rows 7 and 8 are 0.2 and 0.1 s before the next fix but 0.4 and 0.5 s after the last:
    # lost, as the filter's (the backward pass would carry that fix back with the forward
    # filter's orientation, on the gyroscope alone since the last fix)
    assert list(status) == [LOST, LOST, TRACKED, TRACKED, BRIDGED, BRIDGED, LOST, LOST,
                            LOST, TRACKED, BRIDGED, BRIDGED]


def gap_simulation(seed: int, imu: str = "mpu9255"):
    return simulate("random_reach", seed=seed, imu=imu, duration=12.0,
                    occlusions=OcclusionSpec(gap_range=(0.2, 0.3), spacing=1.0))


def test_inside_gaps_the_smoother_beats_the_filter():
    for seed in range(3):
        sim = gap_simulation(seed)
        run = run_smoother(sim.recording, monitor=None)  # the model's covariances, unscaled
        smoothed = metrics_from_errors(gap_errors(run.result, sim.truth.position,
                                                  sim.truth.occluded))
        filtered = metrics_from_errors(gap_errors(run.filtered, sim.truth.position,
                                                  sim.truth.occluded))
        assert smoothed["samples"] > 50
        assert smoothed["rms_mm"] < 0.6 * filtered["rms_mm"]
        assert smoothed["max_mm"] < filtered["max_mm"]
        # and it is more certain there
        gap = sim.truth.occluded
        assert np.all(run.result.std[gap] <= run.filtered.std[gap] + 1e-12)


def test_smoothed_rows_at_the_last_fix_equal_the_filter_and_fixes_stay_tracked():
    sim = gap_simulation(1)
    run = run_smoother(sim.recording)
    last = np.flatnonzero(run.result.status == TRACKED)[-1]
    # the forward filter's last state (run_filter: the same filter; the monitor only reads it)
    filtered = run_filter(sim.recording, monitor=None)
    np.testing.assert_allclose(run.x[-1], filtered.x[-1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.P[-1], filtered.P[-1], rtol=1e-12, atol=0)
    assert set(run.result.status[~sim.truth.occluded]) == {TRACKED}
    assert set(run.result.status[sim.truth.occluded]) == {BRIDGED}
    assert last == len(run.result) - 1 or not sim.truth.occluded[last]


def test_smoother_uses_gated_frames_as_nothing():
    sim = gap_simulation(2)
    position = sim.recording.mocap.position.copy()
    row = int(np.flatnonzero(sim.recording.mocap.visible[300:])[0]) + 300
    position[row] += [0.0, 0.0, 0.08]
    recording = sim.recording.with_mocap(MocapFrames(sim.recording.mocap.t, position,
                                                     sim.recording.mocap.quaternion))
    run = run_smoother(recording)
    assert run.outcome[row] == GATED
    assert np.linalg.norm(run.result.position[row] - sim.truth.position[row]) < 0.002


def test_smooth_recording_through_the_method_registry():
    sim = gap_simulation(0)
    result = track_with_method(sim.recording, "smoother")
    assert result.method == "smoother" and len(result) == len(sim.recording.mocap)
    again = smooth_recording(sim.recording)
    np.testing.assert_array_equal(result.position, again.position)
    # the lever-arm states go through the smoother too
    unknown = dataclasses.replace(sim.recording,
                                  info=dataclasses.replace(sim.recording.info, lever_arm=None))
    run = run_smoother(unknown)
    assert run.x.shape[1] == 12 and np.isfinite(run.result.position).all()
