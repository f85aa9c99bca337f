"""A monitor or hold-out bin shrinks the bound below the profile's only with enough rows
(:func:`kfusion.monitor.rows_to_shrink`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kfusion.monitor import HorizonScales, MonitorParameters, rows_to_shrink


def test_rows_to_shrink_by_hand():
    # the largest of n rows is below the q-quantile with probability q^n; need q^n <= 1/2
    assert rows_to_shrink(0.995) == 139  # 0.995^138 = 0.501, 0.995^139 = 0.498
    assert 0.995 ** 138 > 0.5 > 0.995 ** 139
    assert rows_to_shrink(0.99) == 69
    assert rows_to_shrink(0.5) == 1
    assert rows_to_shrink(1.0) == 1


def test_a_bin_with_few_rows_keeps_the_profile():
    params = MonitorParameters(horizon_edges_s=(0.1, 0.2), minimum_shadow_gaps=1,
                               matching_quantile=0.99, minimum_scale=0.01)
    scales = HorizonScales(params)
    # 20 gaps of 3 rows each in bin 0 (60 rows < 69), all needing 0.1: not yet allowed below 1
    for _ in range(20):
        scales.add_gap([0.05, 0.06, 0.07], [0.1, 0.1, 0.1])
    assert scales.scale_table().tolist() == [1.0, 1.0]
    # larger scales are taken from any evidence (inflating is always allowed)
    scales.add_gap([0.15], [4.0])
    assert scales.scale_table().tolist() == [1.0, 4.0]
    # with 69 rows the matched quantile (0.1) applies
    for _ in range(3):
        scales.add_gap([0.05, 0.06, 0.07], [0.1, 0.1, 0.1])
    assert scales.scale_table()[0] == pytest.approx(0.1)


@pytest.mark.broad
def test_smoother_bound_holds_on_a_short_real_recording():
    # the first 30 s of BROAD trial 21 with 0.1-0.3 s gaps: the hold-out's 16 gaps put 20-60
    # rows in each bin, whose largest required scale was 0.12-0.16; applied, 36 % of the
    # bridged rows were beyond the 99 % bound (3-sigma coverage 0.68)
    from kfusion.config import first_seconds
    from kfusion.datasets import broad_trials
    from kfusion.evaluate import cut_gaps
    from kfusion.kalman import run_smoother
    from kfusion.readers.broad import read_broad

    path = next(path for path in broad_trials() if path.name.startswith("21"))
    recording = first_seconds(read_broad(path, mocap_step=3), 30.0)
    gapped = cut_gaps(recording, rng=np.random.default_rng(0), gap_range=(0.1, 0.3))
    result = run_smoother(gapped.recording).result
    rows = gapped.gap_mask & (np.asarray(result.status) == "bridged")
    assert rows.sum() > 200
    error = np.asarray(result.position)[rows] - np.asarray(gapped.truth_position)[rows]
    std = np.asarray(result.std)[rows]
    coverage = float(np.mean((np.abs(error) <= 3 * std).all(axis=1)))
    assert coverage >= 0.97, coverage


@pytest.mark.broad
def test_the_hold_out_keeps_its_own_refusal_limit():
    # BROAD 24 (tapping) with its knocks modelled as smooth motion (the impact rule off:
    # impact_jerk inf) needs a hold-out std scale above the online monitor's limit of 2 (2.2;
    # 1.2 with the rule); matched on the recording's own gaps it covers them (the online limit
    # would refuse them)
    from kfusion.datasets import broad_trials
    from kfusion.evaluate import cut_gaps
    from kfusion.kalman import run_smoother
    from kfusion.monitor import MonitorParameters
    from kfusion.readers.broad import read_broad

    path = next(path for path in broad_trials() if path.name.startswith("24"))
    gapped = cut_gaps(read_broad(path, mocap_step=3), rng=np.random.default_rng(0),
                      gap_range=(0.1, 0.3))
    run = run_smoother(gapped.recording, impact_jerk=math.inf)
    assert run.holdout is not None
    assert np.sqrt(run.holdout.scale_table().max()) > MonitorParameters().max_std_scale
    status = np.asarray(run.result.status)[gapped.gap_mask]
    assert (status == "bridged").mean() > 0.99
    rows = gapped.gap_mask & (np.asarray(run.result.status) == "bridged")
    error = np.asarray(run.result.position)[rows] - np.asarray(gapped.truth_position)[rows]
    coverage = float(np.mean((np.abs(error) <= 3 * np.asarray(run.result.std)[rows]).all(axis=1)))
    assert coverage >= 0.95, coverage


def test_no_shrinking_beyond_the_evidence_by_hand():
    from kfusion.monitor import scale_beyond_evidence

    edges = (0.1, 0.3)
    np.testing.assert_allclose(scale_beyond_evidence([0.5, 0.5, 2.0], [0.2, 0.31, 0.9], edges),
                               [0.5, 1.0, 2.0])
