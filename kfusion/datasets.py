"""Where the real data live: the BROAD trials and the excerpt bundled with kfusion.

BROAD (Laidig et al., Data 6(7):72, 2021, CC BY 4.0) is public: repository dlaidig/broad,
folder ``data_mat/``. kfusion ships only a 36 s excerpt of trial 21 as a recording folder
(:func:`broad_excerpt`, attribution in ``kfusion/data/README.md``). The full ``.mat`` trials are
looked up in this order:

1. the ``KFUSION_BROAD_DIR`` environment variable (a folder holding the ``.mat`` files);
2. ``shared/data/broad`` in the current directory or any parent of it;
3. ``shared/data/broad`` in any parent of the installed package (a source checkout whose parent
   folder holds ``shared/``).
"""

from __future__ import annotations

import os
from pathlib import Path

ENVIRONMENT_VARIABLE = "KFUSION_BROAD_DIR"
RELATIVE_LOCATION = Path("shared") / "data" / "broad"
SOURCE = "public repository dlaidig/broad, folder data_mat/"
EXCERPT_DIRECTORY = Path(__file__).resolve().parent / "data" / "broad_21_excerpt"


def broad_excerpt() -> Path:
    """The bundled recording folder: 36 s of BROAD trial 21 (fast combined motion, mocap every
    3rd sample, two real dropouts); see ``kfusion/data/README.md``."""
    return EXCERPT_DIRECTORY


def _candidates() -> list[Path]:
    candidates = []
    if os.environ.get(ENVIRONMENT_VARIABLE):
        candidates.append(Path(os.environ[ENVIRONMENT_VARIABLE]))
    for base in (Path.cwd(), Path(__file__).resolve().parent):
        candidates.extend(parent / RELATIVE_LOCATION for parent in (base, *base.parents))
    return candidates


def _searched() -> str:
    """Where :func:`broad_directory` looked, in one line."""
    variable = os.environ.get(ENVIRONMENT_VARIABLE)
    places = [f"{ENVIRONMENT_VARIABLE}={variable}" if variable else f"{ENVIRONMENT_VARIABLE} unset"]
    places += [f"{RELATIVE_LOCATION} in {base} and its parents"
               for base in (Path.cwd(), Path(__file__).resolve().parent)]
    return "; ".join(places)


def broad_available() -> bool:
    """True when :func:`broad_directory` finds the ``.mat`` trials."""
    return any(candidate.is_dir() and any(candidate.glob("*.mat")) for candidate in _candidates())


def broad_directory() -> Path:
    """The folder holding the BROAD ``.mat`` trials; ValueError saying where it looked."""
    for candidate in _candidates():
        if candidate.is_dir() and any(candidate.glob("*.mat")):
            return candidate
    raise ValueError(
        f"BROAD trials not found (looked at: {_searched()}); download the .mat files from the "
        f"{SOURCE} and set {ENVIRONMENT_VARIABLE} to their folder"
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
