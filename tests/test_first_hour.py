"""What a newcomer meets first: light start-up, readable result tables, the stream's --start."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd

from kfusion.cli import main
from kfusion.datasets import broad_excerpt
from kfusion.experiment import write_table_csv

HEAVY_MODULES = ("numpy", "pandas", "pyarrow", "matplotlib", "dask", "scipy")


def modules_loaded_by(code: str) -> list[str]:
    """Which of the heavy libraries a fresh interpreter has loaded after running ``code``."""
    probe = (f"{code}\nimport sys\n"
             f"print('loaded:', *(m for m in {HEAVY_MODULES!r} if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          check=True)
    *printed, last = done.stdout.splitlines()
    print(*printed, sep="\n")  # what ``code`` printed (shown with ``pytest -s``)
    return last.split()[1:]


def test_version_and_help_load_no_numerical_library():
    assert modules_loaded_by("from kfusion.cli import build_parser\n"
                             "build_parser(['--version'])") == []
    assert modules_loaded_by("from kfusion.cli import main\n"
                             "import contextlib, io\n"
                             "with contextlib.redirect_stdout(io.StringIO()):\n"
                             "    try:\n        main(['--help'])\n"
                             "    except SystemExit:\n        pass") == []


def test_the_tracker_loads_neither_pandas_nor_plotting_nor_dask():
    loaded = modules_loaded_by("import time\nstart = time.perf_counter()\n"
                               "import kfusion.tracker\n"
                               "print(f'import kfusion.tracker: {time.perf_counter() - start:.3f}"
                               " s (fresh interpreter)')")
    assert "numpy" in loaded and "scipy" in loaded  # what the filter needs
    assert not {"pandas", "pyarrow", "matplotlib", "dask"} & set(loaded)


RUNNING_TRACKER = """
from kfusion import Tracker
for method in ("kalman", "baseline"):
    tracker = Tracker([1, 0, 0, 0], [0, -9.81, 0], method=method)
    for i in range(400):
        t = i * 0.005
        tracker.push_imu(t, [0.0, 9.81, 0.0], [0.0, 0.0, 0.1])
        if i % 2 == 0:
            visible = not 200 <= i < 300
            tracker.push_mocap(t, [0.0, 0.0, 0.0] if visible else None,
                               [1.0, 0.0, 0.0, 0.0] if visible else None)
    tracker.estimate(2.0).bound(0.99)
    tracker.restore(tracker.snapshot())
    tracker.health.as_dict()
    tracker.consistency
"""


def test_a_running_tracker_loads_neither_pandas_nor_plotting_nor_dask():
    """Not only the import: pushing, a gap, estimate, bound, snapshot, health, the monitor."""
    loaded = modules_loaded_by(RUNNING_TRACKER)
    assert "numpy" in loaded
    assert not {"pandas", "pyarrow", "matplotlib", "dask"} & set(loaded)
    # the probe sees a heavy module when there is one (negative control)
    assert "pandas" in modules_loaded_by(RUNNING_TRACKER + "import pandas")


def test_result_tables_carry_no_float_noise(tmp_path):
    table = pd.DataFrame({"gap_start_s": [0.1 + 0.02, 1.0], "samples": [416.0, 12.0],
                          "rms_mm": [2.0 / 3.0, np.nan], "gaps": [3.0, np.nan]})
    assert table.loc[0, "gap_start_s"] == 0.12000000000000001  # what to_csv would write
    text = write_table_csv(table, tmp_path / "t.csv", index=False).read_text().splitlines()
    assert text == ["gap_start_s,samples,rms_mm,gaps", "0.12,416,0.6666666667,3", "1,12,,"]


def test_stream_start_prints_from_that_time_on(capsys):
    folder = str(broad_excerpt())
    assert main(["stream", folder, "--start", "64.5", "--every", "5", "--count", "4"]) == 0
    times = [float(line.split()[0][2:]) for line in capsys.readouterr().out.splitlines()]
    assert len(times) == 4 and times[0] >= 64.5 and times[0] - 64.5 < 0.011  # mocap ~95 Hz
    np.testing.assert_allclose(np.diff(times), 5 * 3 * 0.0035, atol=0.001)  # printed to 1 ms
