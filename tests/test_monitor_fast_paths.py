"""The consistency monitor's faster forms against the plain ones they replace.

The monitored batch filter spends most of its time in the monitor's Python bookkeeping, so
several of its steps have a second form: a stacked one (many rows in one numpy call), an
incremental one (a bin's sorted rows kept between shadow gaps), or one in Python floats. Each is
checked here against the straightforward computation: numpy's own quantile, a sort of the rows,
LAPACK's solve, the matrix products, and the monitor's per-row reads (row by row, as the Tracker
makes them). The stacked forms must give each row the bits of the single-row call (the batch
filter and the Tracker agree bit for bit), so those comparisons are exact."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kfusion.kalman import model
from kfusion.kalman.monitored import _selected_points
from kfusion.monitor import (
    HorizonScales,
    MonitorParameters,
    fix_covariance_under_innovation_factor,
    fix_covariance_under_scale,
    fix_covariances_widened,
    linear_quantile,
    normalised_error_squared,
    normalised_errors_squared,
    positive_part,
    quantile_matching_scale,
    required_scale,
    required_scales,
    shadow_row_scales,
    shadow_rows_scales,
)

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)


@settings(max_examples=300, deadline=None)
@given(st.lists(finite, min_size=1, max_size=60),
       st.floats(min_value=0.0, max_value=1.0))
def test_linear_quantile_is_numpys_to_the_bit(values: list[float], quantile: float) -> None:
    expected = float(np.quantile(np.array(values), quantile))
    assert linear_quantile(sorted(values), quantile) == expected


def test_quantile_matching_scale_against_numpy_with_nan_and_inf() -> None:
    rng = np.random.default_rng(3)
    values = rng.gamma(2.0, size=500).tolist()
    with_missing = values + [math.nan] * 7
    assert quantile_matching_scale(with_missing, 0.995) == np.quantile(values, 0.995)
    # inf rows below the 1 - c share are dropped; above it the scale is inf
    assert quantile_matching_scale(values + [math.inf], 0.995) == np.quantile(values, 0.995)
    assert quantile_matching_scale(values[:100] + [math.inf], 0.995) == math.inf


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(st.tuples(st.sampled_from([0.01, 0.03, 0.05, 0.12, 0.25, 0.4]),
                                   st.one_of(st.floats(min_value=0.0, max_value=50.0),
                                             st.just(math.inf), st.just(math.nan))),
                         min_size=0, max_size=12),
                min_size=1, max_size=15))
def test_horizon_scales_sorted_rows_equal_sorting_the_memory(gaps: list[list[tuple[float, float]]]
                                                             ) -> None:
    """Each bin's matched scale, read from the rows kept sorted as gaps arrive and old rows
    leave the memory (here 7 rows per bin), equals quantile_matching_scale of the rows in the
    memory, also in copies taken on the way."""
    params = dataclasses.replace(MonitorParameters(), memory=7)
    scales = HorizonScales(params)
    copies = []
    for gap in gaps:
        horizons = [horizon for horizon, _ in gap]
        scales.add_gap(horizons, [value for _, value in gap])
        copies.append((scales.copy(), [list(rows) for rows in scales._rows]))
        scales = scales.copy()  # the monitor continues on a copy (the kept ones stay as they are)
    for copy, memory in copies:
        expected = tuple(quantile_matching_scale(rows, params.matching_quantile)
                         for rows in memory)
        np.testing.assert_array_equal(copy.variance_scales(), expected)
        assert copy.largest_scale() == max(copy.scale_table().tolist())


def random_covariances(rng: np.random.Generator, count: int) -> np.ndarray:
    """(count, 3, 3) symmetric positive definite matrices over 10 decades of scale."""
    factors = rng.normal(size=(count, 3, 3))
    scale = 10.0 ** rng.uniform(-9, 1, size=count)
    return (factors @ factors.transpose(0, 2, 1) + 0.01 * np.eye(3)) * scale[:, None, None]


def test_normalised_error_squared_in_floats_against_lapack() -> None:
    rng = np.random.default_rng(5)
    covariances = random_covariances(rng, 400)
    errors = rng.normal(size=(400, 3)) * np.sqrt(covariances[:, 0, 0])[:, None]
    for error, covariance in zip(errors, covariances, strict=True):
        expected = float(error @ np.linalg.solve(covariance, error))
        assert normalised_error_squared(error, covariance) == pytest.approx(expected, rel=1e-9)
    # a permutation needs the pivoting: a zero first pivot
    swapped = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 2.0]])
    assert normalised_error_squared([1.0, 2.0, 2.0], swapped) == pytest.approx(4.0 + 2.0)
    singular = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert normalised_error_squared([1.0, 0.0, 0.0], singular) == math.inf
    assert normalised_error_squared([math.nan, 0.0, 0.0], np.eye(3)) == math.inf
    assert normalised_error_squared([1.0, 0.0, 0.0], np.full((3, 3), math.inf)) == math.inf
    np.testing.assert_allclose(normalised_errors_squared(errors, covariances),
                               [normalised_error_squared(e, P) for e, P
                                in zip(errors, covariances, strict=True)], rtol=1e-9)


def test_stacked_scales_give_each_row_the_single_rows_bits() -> None:
    """required_scales and shadow_rows_scales over a stack (singular and non-finite rows
    among them, and rows needing Newton's iteration) equal the single-row calls exactly."""
    rng = np.random.default_rng(11)
    covariances = random_covariances(rng, 60) * 1e-4
    errors = rng.normal(size=(60, 3)) * 3e-3
    covariances[7] = 0.0  # singular
    covariances[9, 1, 1] = math.nan
    errors[13] = math.inf
    noise = 10.0 ** rng.uniform(-8, -5, size=60)
    innovation, prediction = shadow_rows_scales(errors, covariances, noise)
    assert 10 < int(np.sum(np.isfinite(prediction) & (prediction > 1.0))) < 50
    for row in range(60):
        single = shadow_row_scales(errors[row], covariances[row], noise[row])
        assert single == (innovation[row], prediction[row]) or (
            math.isinf(single[0]) and math.isinf(innovation[row]))
    np.testing.assert_array_equal(required_scales(errors, covariances),
                                  [required_scale(e, P) for e, P
                                   in zip(errors, covariances, strict=True)])


def test_widened_fix_covariances_stacked_alone_and_by_the_matrix_products() -> None:
    """fix_covariances_widened over a stack equals each row alone (the Tracker's at_fix) to the
    bit, and equals the formula written with the matrix products to rounding; rows that are
    not clearly positive definite take the eigendecomposition, infinite factors give inf."""
    rng = np.random.default_rng(2)
    noise = 1e-6
    covariances = random_covariances(rng, 40)
    covariances = covariances / covariances[:, 0, 0][:, None, None] * \
        rng.uniform(0.05, 1.5, size=40)[:, None, None] * noise  # some above R: clipped parts
    scales = rng.choice([1.0, 0.5, 1.7, 3.0, math.inf], size=40)
    factors = rng.choice([1.0, 2.0, 4.5], size=40)
    stacked = fix_covariances_widened(covariances, noise, scales, factors)
    for row in range(40):
        alone = fix_covariances_widened(covariances[row][None], noise, scales[row:row + 1],
                                        factors[row:row + 1])[0]
        np.testing.assert_array_equal(alone, stacked[row])
        P, scale, factor = covariances[row], scales[row], factors[row]
        if math.isinf(scale):
            assert np.isinf(stacked[row]).all()
            continue
        expected = P.copy()
        if scale > 1.0:
            correction = P - P @ P / noise
            expected = expected + (scale - 1.0) * positive_part(0.5 * (correction + correction.T))
        if factor > 1.0:
            expected = expected + (factor - 1.0) * positive_part(noise * np.eye(3)
                                                                 - 0.5 * (P + P.T))
        np.testing.assert_allclose(stacked[row], expected, rtol=1e-12, atol=1e-24)
    # the single-finding forms are the stacked one with the other factor 1
    np.testing.assert_array_equal(fix_covariance_under_scale(covariances[0], noise, 2.5),
                                  fix_covariances_widened(covariances[:1], noise,
                                                          np.array([2.5]), np.ones(1))[0])
    np.testing.assert_array_equal(
        fix_covariance_under_innovation_factor(covariances[0], noise, 3.0),
        fix_covariances_widened(covariances[:1], noise, np.ones(1), np.array([3.0]))[0])


def test_selected_points_are_the_output_maps_bits_and_only_for_the_selector() -> None:
    rng = np.random.default_rng(4)
    rows, size = 12, model.BASE_SIZE
    x = rng.normal(size=(rows, size))
    factors = rng.normal(size=(rows, size, size))
    P = factors @ factors.transpose(0, 2, 1)
    H = np.broadcast_to(model.measurement_matrix(size), (rows, 3, size)).copy()
    offset = rng.normal(size=(rows, 3)) * 0.01
    points = _selected_points(x, P, H, offset)
    assert points is not None
    for row in range(rows):
        np.testing.assert_array_equal(points[0][row], model.output_point(H[row], x[row],
                                                                         offset[row]))
        np.testing.assert_array_equal(points[1][row], model.output_covariance(H[row], P[row]))
        np.testing.assert_array_equal(points[2][row], x[row, model.VELOCITY])
    lever = np.broadcast_to(model.measurement_matrix(model.BASE_SIZE + 3, np.eye(3)),
                            (rows, 3, model.BASE_SIZE + 3))
    assert _selected_points(np.zeros((rows, size + 3)), np.zeros((rows, size + 3, size + 3)),
                            lever, offset) is None
    P[3, 0, 0] = math.inf
    assert _selected_points(x, P, H, offset) is None  # 0 * inf is NaN in the products


def test_means_of_huge_windows_are_inf_not_an_error() -> None:
    """sum_mean (math.fsum) raises on finite values summing beyond the largest float; the NIS
    window's tests then give numpy's mean, inf, as before."""
    from kfusion.monitor import nis_matching_scale, sum_mean, windowed_nis_test

    huge = [1e308, 1e308, 3.0]
    assert sum_mean(huge) == math.inf
    assert windowed_nis_test(huge).mean == math.inf
    assert nis_matching_scale(huge) == math.inf
    assert sum_mean([1.0, 2.0, 4.0]) == 7.0 / 3.0


def test_a_snapshot_of_another_state_format_is_refused() -> None:
    """A TrackerSnapshot carries SNAPSHOT_FORMAT in its configuration: one pickled by a
    version of kfusion whose state had another shape is refused with a ValueError, not restored
    to fail later."""
    from kfusion import tracker as tracker_module
    from kfusion.tracker import Tracker

    tracker = Tracker(imu_to_body=[1.0, 0.0, 0.0, 0.0], gravity=[0.0, 0.0, -9.81])
    snapshot = tracker.snapshot()
    older = dataclasses.replace(snapshot, _configuration=(
        tracker_module.SNAPSHOT_FORMAT - 1, *snapshot._configuration[1:]))
    with pytest.raises(ValueError, match="state format"):
        tracker.restore(older)
    tracker.restore(snapshot)
