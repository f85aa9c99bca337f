"""Shared test set-up. The full BROAD set is optional (a plain clone has only the excerpt bundled
in ``kfusion/data``): a test marked ``@pytest.mark.broad`` needs the seven ``.mat`` trials and
skips with one line when they are not found."""

from __future__ import annotations

import pytest

from kfusion.datasets import ENVIRONMENT_VARIABLE, broad_available

BROAD_SKIP_REASON = (f"full BROAD trials not found (set {ENVIRONMENT_VARIABLE}, see README "
                     "'Real data'); the bundled excerpt is tested instead")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "broad: needs the full BROAD trials (skips without them)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if broad_available():
        return
    skip = pytest.mark.skip(reason=BROAD_SKIP_REASON)
    for item in items:
        if item.get_closest_marker("broad") is not None:
            item.add_marker(skip)
