"""``benchmarks/tracker_latency.py`` runs: its no-op estimator keeps up with the Tracker's
estimator interface (a new method there broke the benchmark once, unseen by the suite)."""

from __future__ import annotations

from benchmark_module import load_benchmark


def test_the_latency_benchmark_runs_its_table(capsys):
    benchmark = load_benchmark("tracker_latency")
    assert benchmark.main(["--seconds", "5"]) == 0
    table = capsys.readouterr().out
    for label in ("| kalman | in order |", "| no-op estimator | mocap first |",
                  "| estimator alone | in order |"):
        assert label in table


def test_the_no_op_estimator_has_every_method_of_the_interface():
    from kfusion.tracker import _Estimator

    benchmark = load_benchmark("tracker_latency")
    wanted = {name for name in vars(_Estimator) if not name.startswith("_")}
    assert wanted <= set(dir(benchmark.NoOpEstimator))
