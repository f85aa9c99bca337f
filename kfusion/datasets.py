"""Where the bundled real data live: the BROAD trials (see ``shared/data/broad/README.md``).

The trials sit outside the package, in ``shared/data/broad`` beside the repository checkout. The
folder is looked up in this order:

1. the ``KFUSION_BROAD_DIR`` environment variable;
2. ``shared/data/broad`` in the current directory or any parent of it;
3. ``shared/data/broad`` beside the repository that holds this package (source checkouts).
"""

from __future__ import annotations

import os
from pathlib import Path

ENVIRONMENT_VARIABLE = "KFUSION_BROAD_DIR"
RELATIVE_LOCATION = Path("shared") / "data" / "broad"


def _candidates() -> list[Path]:
    candidates = []
    if os.environ.get(ENVIRONMENT_VARIABLE):
        candidates.append(Path(os.environ[ENVIRONMENT_VARIABLE]))
    for base in (Path.cwd(), Path(__file__).resolve().parent):
        candidates.extend(parent / RELATIVE_LOCATION for parent in (base, *base.parents))
    return candidates


def broad_directory() -> Path:
    """The folder holding the BROAD ``.mat`` trials; ValueError saying where it looked."""
    for candidate in _candidates():
        if candidate.is_dir() and any(candidate.glob("*.mat")):
            return candidate
    raise ValueError(
        f"BROAD trials not found: set {ENVIRONMENT_VARIABLE} or place them in "
        f"{RELATIVE_LOCATION} beside the checkout (looked in {_candidates()[0]} and its parents)"
    )


def broad_trials() -> list[Path]:
    """Paths of every BROAD trial file, sorted by name (e.g. ``01_undisturbed_slow_...mat``)."""
    return sorted(broad_directory().glob("*.mat"))


def broad_trial(key: str) -> Path:
    """The trial whose file name starts with ``key`` (e.g. ``"21"``); ValueError if not one."""
    matches = [path for path in broad_trials() if path.name.startswith(key)]
    if len(matches) != 1:
        names = [path.stem for path in broad_trials()]
        raise ValueError(f"BROAD trial {key!r}: expected exactly one match in {names}, "
                         f"got {len(matches)}")
    return matches[0]
