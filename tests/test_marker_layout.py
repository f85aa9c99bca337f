"""The marker layout checked against the data (kfusion.kalman.marker_layout): hand checks of
the residuals, the correction rule and the common error, and marker-level fusion with one
marker off its layout."""

from __future__ import annotations

import numpy as np

from kfusion.kalman import run_filter, run_smoother
from kfusion.kalman.batch import make_fusion, process_recording, resolve_parameters
from kfusion.kalman.marker_layout import (
    LONG_FRAMES,
    MIN_FRAMES,
    SIGNIFICANCE,
    UNSETTLED_FRAMES,
    LayoutResiduals,
    corrected_markers,
    origin_variance,
    residual_shares,
    residuals,
    single_marker_gain,
    spread_excess,
)
from kfusion.kalman.markers import fit_angle_variance
from kfusion.simulate import MarkerSpec, OcclusionSpec, simulate
from kfusion.tracker import position_bound

SQUARE = np.array([[0.03, 0.0, 0.0], [0.0, 0.03, 0.0], [-0.03, 0.0, 0.0], [0.0, -0.03, 0.0]])
"""m: four markers on a circle about the body origin."""


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_residuals_are_zero_for_the_true_layout_and_absorb_a_rigid_shift():
    R, p = rotation_z(0.7), np.array([0.4, -0.2, 1.1])
    seen = SQUARE @ R.T + p
    assert np.allclose(residuals(seen, SQUARE), 0.0, atol=1e-12)
    shifted = (SQUARE + [0.001, -0.002, 0.0005]) @ R.T + p  # every marker: a rigid change
    assert np.allclose(residuals(shifted, SQUARE), 0.0, atol=1e-12)


def test_one_marker_moved_outwards_by_hand():
    """Marker 0 of the square 1 mm further out (along its own arm): no rotation absorbs it,
    the fit's centroid takes a quarter, so ``r_0 = 3/4 delta`` and ``r_i = -1/4 delta``."""
    delta = np.array([0.001, 0.0, 0.0])
    R, p = rotation_z(-1.2), np.array([0.1, 0.2, 0.3])
    true = SQUARE.copy()
    true[0] += delta
    r = residuals(true @ R.T + p, SQUARE)
    assert np.allclose(r[0], 0.75 * delta, atol=1e-12)
    assert np.allclose(r[1:], -0.25 * delta, atol=1e-12)


def layout_with(mean: np.ndarray, body: np.ndarray = SQUARE, frames: int = 1000
                ) -> LayoutResiduals:
    """A layout whose long and recent mean residuals are both ``mean`` (n, 3) m."""
    return LayoutResiduals(body, mean.copy(), np.full(len(body), min(frames, LONG_FRAMES)),
                           mean.copy(), frames)


def test_the_common_error_by_hand():
    """For those residuals, ``sigma_delta^2 = sum |r_i|^2 / (3n - 6) = (3/4) delta^2 / 6``; the
    square's centroid is the origin, so the origin's per-axis variance is ``sigma_delta^2 / 4``;
    uncorrected markers add ``|r_i|^2 / 3`` of the largest."""
    delta = 0.001
    mean = np.zeros((4, 3))
    mean[0, 0], mean[1:, 0] = 0.75 * delta, -0.25 * delta
    tiny, huge = (1e-6) ** 2, 1.0  # marker variances: every mean significant, or none
    assert corrected_markers(layout_with(mean), tiny).all()
    assert not corrected_markers(layout_with(mean), huge).any()
    # none significant: independent errors, and the largest uncorrected residual
    assert np.isclose(origin_variance(layout_with(mean), huge),
                      0.75 * delta ** 2 / 6 / 4 + (0.75 * delta) ** 2 / 3)
    # significant (one marker off, most likely): at least the single-marker gain's term,
    # 1/4 sum |r_i|^2 / 3 for the square, which is the larger here
    assert np.isclose(origin_variance(layout_with(mean), tiny), 0.25 * 0.75 * delta ** 2 / 3)
    # off the origin the fit's rotation error moves the origin too: |mbar|^2 sigma_theta^2
    offset = SQUARE + [0.0, 0.0, 0.05]
    layout_variance = 0.75 * delta ** 2 / 6
    independent = layout_variance / 4 + 0.05 ** 2 * fit_angle_variance(offset, layout_variance)
    assert np.isclose(origin_variance(layout_with(mean, offset), huge),
                      independent + (0.75 * delta) ** 2 / 3)
    assert np.isclose(origin_variance(layout_with(mean, offset), tiny),
                      max(independent, single_marker_gain(offset) * 0.75 * delta ** 2 / 3))


def test_single_marker_gain_by_hand_and_by_sampling():
    """One marker of the square moved out of its plane by delta: the best plane is
    ``z = delta/4 + delta x / (2a)``, so every residual is ``delta/4`` in size and the origin
    moves ``delta/4``: ``|o|^2 / sum |r|^2 = (1/16) / (4/16) = 1/4``, the largest any one
    marker gives. Sampled single-marker errors never exceed the gain, and reach it; a
    3-marker cluster hides a marker moved out of its plane (infinite gain)."""
    from kfusion.rigid_body import fit_pose

    assert np.isclose(single_marker_gain(SQUARE), 0.25)
    assert single_marker_gain(SQUARE[:3]) == np.inf
    rng = np.random.default_rng(3)
    for body in (SQUARE, SQUARE + [0.0, 0.0, -0.15],
                 np.array([[0.02, -0.02, 0.0], [-0.05, -0.01, -0.03], [-0.01, -0.08, 0.01],
                           [-0.05, -0.05, -0.05]])):
        gain, largest = single_marker_gain(body), 0.0
        for _ in range(3000):
            true = body.copy()
            error = rng.standard_normal(3)
            true[rng.integers(len(body))] += 1e-5 * error / np.linalg.norm(error)
            rotation, origin = fit_pose(body, true)  # the layout fitted to the moved markers
            r = (true - origin) @ rotation - body
            largest = max(largest, float(origin @ origin / np.sum(r * r)))
        assert largest <= gain * (1 + 1e-3)
        assert largest >= 0.95 * gain


def test_a_recent_residual_away_from_the_correction_is_covered():
    """A corrected marker whose recent mean left its long one (knocked since): the recent
    mean counts, and what the correction leaves of it is covered whole."""
    tiny = (1e-6) ** 2
    mean = np.zeros((4, 3))
    mean[0, 0], mean[1:, 0] = 0.75e-3, -0.25e-3
    layout = layout_with(mean)
    recent = mean.copy()
    recent[2] = [0.0, 0.6e-3, 0.0]
    moved = LayoutResiduals(SQUARE, mean, layout.long_frames, recent, layout.frames)
    squared = np.sum(recent * recent)  # the recent mean of marker 2, the long one elsewhere
    assert np.isclose(origin_variance(moved, tiny),
                      max(squared / 6 / 4, 0.25 * squared / 3)
                      + np.sum((recent[2] - mean[2]) ** 2) / 3)


def test_a_marker_is_corrected_only_when_its_mean_residual_is_significant():
    variance = (0.5e-3) ** 2
    mean = np.zeros((4, 3))
    mean[2] = [0.2e-3, 0.0, 0.0]
    # N |r|^2 / sigma^2 = N 0.16: significant from N = 102 on
    frames = int(np.ceil(SIGNIFICANCE / 0.16))
    assert not corrected_markers(layout_with(mean, frames=frames - 1), variance).any()
    assert corrected_markers(layout_with(mean, frames=frames), variance).tolist() == \
        [False, False, True, False]
    assert not corrected_markers(layout_with(10.0 * mean, frames=MIN_FRAMES - 1),
                                 variance).any()


def test_layout_residuals_accumulate_against_the_declared_layout():
    variance = (0.5e-3) ** 2
    layout = LayoutResiduals.start(SQUARE)
    true = SQUARE.copy()
    true[1] += [0.0, 0.002, 0.0]
    for angle in (0.0, 0.5, 1.0):
        layout = layout.with_frame(true @ rotation_z(angle).T, variance)
    assert layout.frames == 3
    np.testing.assert_allclose(layout.long_mean[1], [0.0, 0.0015, 0.0], atol=1e-12)
    np.testing.assert_allclose(layout.short_mean, layout.long_mean, atol=1e-12)
    assert layout.matches(SQUARE.copy()) and not layout.matches(true)


def test_a_marker_knocked_later_restarts_its_mean():
    """300 frames on the declared layout, then marker 1 knocked 2 mm: its recent mean leaves
    the long one within a few frames and the long mean restarts from it, so 40 frames on it
    holds most of the new residual (1.5 mm), where a mean over all 340 frames held 12 %."""
    variance = (0.5e-3) ** 2
    layout = LayoutResiduals.start(SQUARE)
    for angle in np.linspace(0.0, 3.0, 300):
        layout = layout.with_frame(SQUARE @ rotation_z(angle).T, variance)
    assert not corrected_markers(layout, variance).any()
    knocked = SQUARE.copy()
    knocked[1] += [0.0, 0.002, 0.0]
    for angle in np.linspace(3.0, 3.4, 40):
        layout = layout.with_frame(knocked @ rotation_z(angle).T, variance)
    assert layout.long_mean[1, 1] > 0.8 * 0.0015
    # unsettled for UNSETTLED_FRAMES after the change: not moved yet, covered by its largest
    # recent residual (as an uncorrected marker's, at least |r|^2 / 3)
    assert layout.unsettled.tolist() == [False, True, False, False]
    assert not corrected_markers(layout, variance).any()
    assert origin_variance(layout, variance) >= float(layout.peak[1]) / 3
    assert layout.peak[1] > (0.8 * 0.0015) ** 2
    for angle in np.linspace(3.4, 6.0, UNSETTLED_FRAMES):
        layout = layout.with_frame(knocked @ rotation_z(angle).T, variance)
    assert not layout.unsettled.any()
    assert corrected_markers(layout, variance)[1]


def wobbling_layouts(amplitude: float, frames: int = 1000, seed: int = 4):
    """LayoutResiduals after each frame of the square, marker 0 wobbling ``amplitude`` m
    along its arm at 1 Hz (100 frames a period), 0.5 mm noise on every marker."""
    variance = (0.5e-3) ** 2
    rng = np.random.default_rng(seed)
    layout = LayoutResiduals.start(SQUARE)
    for frame in range(frames):
        wobbling = SQUARE.copy()
        wobbling[0, 0] += amplitude * np.sin(2 * np.pi * frame / 100)
        seen = wobbling @ rotation_z(0.003 * frame).T + rng.normal(0.0, 0.5e-3, (4, 3))
        layout = layout.with_frame(seen, variance)
        yield frame, layout


def test_residual_shares_sum_to_the_fit_s_degrees_of_freedom():
    """A rigid fit takes 6 of the 3n coordinates: the shares sum to 3n - 6; the square's four
    markers are alike (1.5 each), and a marker far from the others keeps less."""
    assert np.allclose(residual_shares(SQUARE), 1.5)
    uneven = np.vstack([SQUARE, [[0.0, 0.0, 0.12]]])
    shares = residual_shares(uneven)
    assert np.isclose(shares.sum(), 3 * 5 - 6)
    assert shares[4] < shares[:4].min()


def test_a_wobbling_marker_is_covered_at_every_phase():
    """Marker 0 wobbling 1 mm at 1 Hz: a mean residual follows it too slowly to show it
    (before, the bound read it near zero at every crossing: 2.7-4.4 % of the rows beyond),
    but its residuals spread beyond the noise's, and the common error covers the wobble's
    peak at every phase: its residual is 0.75 mm at the peak, and the 99 % radius of the
    term alone (3.37 sigma per axis) exceeds that from half of ``0.75^2 / 3`` per axis on."""
    variance = (0.5e-3) ** 2
    smallest = min(origin_variance(layout, variance)
                   for frame, layout in wobbling_layouts(0.001) if frame >= 300)
    assert smallest > 0.5 * (0.75e-3) ** 2 / 3
    assert 3.37 * np.sqrt(0.5 * (0.75e-3) ** 2 / 3) > 0.75e-3


def test_noise_alone_does_not_read_as_a_wobble():
    """The same square without a wobble: the spread of its residuals is the noise's, and the
    excess rule stays off on at least 99 % of the frames."""
    variance = (0.5e-3) ** 2
    on = [bool(spread_excess(layout, variance).any())
          for frame, layout in wobbling_layouts(0.0) if frame >= 100]
    assert np.mean(on) < 0.01


def one_marker_off(size: float):
    """A 25 s random reach, 4-marker cluster (0.5 mm noise), partial occlusions; marker 3
    actually ``size`` m from its declared position (knocked before the take). Returns the
    simulation and the recording with the declared layout."""
    simulation = simulate("random_reach", seed=1, duration=25.0,
                          markers=MarkerSpec(noise=0.5e-3),
                          occlusions=OcclusionSpec(gap_range=(0.1, 0.5), spacing=1.5))
    recording = simulation.recording
    names = recording.markers.names
    body = np.array([recording.info.markers[name] for name in names])
    direction = np.array([0.3, -0.8, 0.5]) / np.linalg.norm([0.3, -0.8, 0.5])
    # the markers were simulated at `body`; declare marker 3 `size` off instead
    declared = dict(recording.info.markers)
    declared[names[3]] = tuple((body[3] - size * direction).tolist())
    info = type(recording.info)(**{**recording.info.__dict__, "markers": declared})
    return simulation, type(recording)(**{**recording.__dict__, "info": info})


def beyond(run, truth) -> tuple[float, float]:
    """(fraction of the rows not lost beyond their 99 % bound, the largest error / bound)."""
    known = run.result.status != "lost"
    error = np.linalg.norm(run.result.position - truth, axis=1)[known]
    bound = np.array([position_bound(np.diag(std ** 2), 0.99) for std in run.result.std[known]])
    return float(np.mean(error > bound)), float(np.max(error / bound))


def test_a_marker_one_millimetre_off_its_layout_keeps_the_bound():
    """Before the layout was checked, the filter had 12-17 % and the smoother half of its rows
    with every or three markers seen beyond the 99 % bound: the fit's common error, which no
    term covered and the smoother averaged as noise."""
    simulation, recording = one_marker_off(0.001)
    truth = simulation.truth.position
    for run in (run_filter(recording, measurement="markers"),
                run_smoother(recording, measurement="markers")):
        share, worst = beyond(run, truth)
        assert share < 0.01
        assert worst < 3.0


def test_a_correct_layout_leaves_a_common_error_that_fades():
    """Without a layout error the term is what the frames so far leave unknown: below
    (0.05 mm)^2 per axis after the first seconds, and no marker is moved."""
    simulation = simulate("random_reach", seed=2, duration=12.0, markers=MarkerSpec(noise=0.5e-3))
    recording = simulation.recording
    fusion = make_fusion(recording, resolve_parameters(recording, None, {}), "filterpy")
    process_recording(recording, fusion, lambda row, outcome: None, None, "markers")
    assert fusion._layout is not None and fusion._layout.frames > 500
    assert fusion.layout_variance < (0.05e-3) ** 2
    assert not fusion._layout_corrected().any()
