"""Experiment configuration files (YAML): schema, validation, loading and the data they name.

A *run config* describes one experiment (``kfusion run CONFIG``)::

    name: arm_lift_type1            # default: the file name without .yaml
    description: ...
    data:                           # what to track and how its gaps are scored
      kind: simulate                # simulate | broad | folder | combined (labelled parts)
      scenario: arm_lift
      imu: mpu9255
      occlusions: {gap_range: [0.1, 0.3], placement: mid_motion}
    methods:                        # method name -> overrides of its parameter object
      baseline: {}
      kalman: {accelerometer_noise_density: 0.003}
    seeds: 5                        # an int n means seeds 0..n-1, or a list [0, 4, 7]
    output: {directory: ..., plots: {axes: [y]}}

A *sweep config* (``kfusion sweep CONFIG``) is a run config plus ``grid``: dotted key paths into
the run config mapped to lists of values, plus the special key ``method`` (one method per run; by
default every method of the ``methods`` section)::

    grid:
      data.occlusions.gap_range: [[0.1, 0.3], [0.3, 0.6]]
      data.imu: [mpu9255, um7]
      methods.kalman.accelerometer_noise_density: [0.001, 0.003]

Every file is checked against the pydantic models below, each expanded grid point included, before
anything runs. A mistake raises :class:`ConfigError` (a ``ValueError``), one line naming the file
and the key path, e.g. ``configs/x.yaml: methods.kalman.acelerometer_noise: unknown parameter;
expected one of [...]``. Estimator parameters are checked against the methods' frozen parameter
dataclasses (:data:`PARAMETER_CLASSES`), so a new field there is accepted here with no edit.

Paths inside a config (BROAD folder, recording folders) are relative to the config file; the
output directory is relative to the current directory (default ``kfusion-output/<name>``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import importlib
import itertools
import json
import os
import types
import typing
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    field_validator,
)

from kfusion.conventions import imu_time_to_mocap
from kfusion.experiment import ScoredRecording
from kfusion.guards import YamlError, load_yaml, short_repr
from kfusion.methods import METHODS
from kfusion.profiles import IMU_PROFILES
from kfusion.recording import ImuSamples, MocapFrames, Recording

QUICK_SIMULATION_S = 15.0
"""Simulated duration, s, in quick mode (``--quick``, smoke tests, quick notebooks)."""
QUICK_RECORDING_S = 30.0
"""Seconds kept of each real recording in quick mode (only the first trial or folder is used)."""
QUICK_GRID_VALUES = 2
"""Values kept per grid axis in quick mode."""
NOTEBOOK_QUICK_VARIABLE = "KFUSION_NOTEBOOK_QUICK"
"""Environment variable that makes the notebooks run on small data (set by the test suite)."""
DEFAULT_OUTPUT_ROOT = Path("kfusion-output")

PARAMETER_CLASSES: dict[str, str] = {
    "baseline": "kfusion.baseline:BaselineParameters",
    "kalman": "kfusion.kalman:KalmanParameters",
    "smoother": "kfusion.kalman:KalmanParameters",
}
"""Method name -> ``module:Class`` of its frozen parameter dataclass; a config's overrides for the
method must be fields of that class. Methods not listed take their overrides unchecked."""

GRID_ROOTS = ("data", "methods")
"""A grid key is ``method`` or a dotted path starting with one of these."""
METRIC_NAMES = ("samples", "rms_mm", "max_mm", "mean_mm", "coverage_3sigma", "lost_fraction",
                "imu_per_second", "gaps", "tracking_s", "runtime_s", "data_s", "total_s")
"""Columns of a sweep's results table that a heat map can show (see :mod:`kfusion.sweep`)."""


# --------------------------------------------------------------------------------------------
# errors


@dataclass(frozen=True)
class ConfigIssue:
    """One problem in a config: dotted key path (``""`` for the top level) and what is wrong."""

    path: str
    message: str
    unknown_key: bool = False


class ConfigError(ValueError):
    """A config file is invalid. ``str()`` is one line: ``FILE: KEY.PATH: problem[; ...]``.

    Attributes:
        file: the config file (as given), or ``"<config>"`` for an in-memory mapping.
        issues: every problem found, each with its dotted key path.
    """

    def __init__(self, file: str | Path | None, issues: Sequence[ConfigIssue]) -> None:
        self.file = str(file) if file is not None else "<config>"
        self.issues = tuple(issues)
        parts = [f"{issue.path}: {issue.message}" if issue.path else issue.message
                 for issue in self.issues]
        super().__init__(f"{self.file}: " + "; ".join(parts))


def _format_path(parts: Iterable[str | int]) -> str:
    text = ""
    for part in parts:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += ("." if text else "") + str(part)
    return text


# --------------------------------------------------------------------------------------------
# schema


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _gap_range_ok(value: tuple[float, float]) -> tuple[float, float]:
    low, high = value
    if not 0 < low <= high:
        raise ValueError(f"expected [min, max] seconds with 0 < min <= max, got {list(value)}")
    return value


GapRange = Annotated[tuple[float, float], Field(description="[min, max] gap length, s")]


class GapsConfig(_Strict):
    """Artificial gaps cut into real recordings where the mocap is valid
    (:func:`kfusion.evaluate.cut_gaps`)."""

    gap_range: GapRange = Field(default=(0.1, 0.3), description="[min, max] gap length, s")
    spacing: float = Field(default=1.0, gt=0, le=600,
                           description="visible time before each gap, s")
    count: int | None = Field(default=None, ge=1,
                              description="maximum number of gaps (null: all)")
    seeding: Literal["per_recording", "shared"] = Field(
        default="per_recording", description="gap patterns: per_recording draws each "
        "recording's from (seed, its name), so it does not depend on the other recordings; "
        "shared draws every recording's from the seed alone (as benchmarks/accuracy.py does)")

    _check_range = field_validator("gap_range")(_gap_range_ok)


class OcclusionsConfig(_Strict):
    """Simulated occlusions (:class:`kfusion.simulate.OcclusionSpec`)."""

    gap_range: GapRange = Field(default=(0.1, 0.3), description="[min, max] gap length, s")
    placement: Literal["random", "mid_motion", "direction_change"] = Field(
        default="random", description="where gaps fall: anywhere; mid-motion (paper Type 1); at "
        "direction changes (paper Type 2)")
    spacing: float = Field(default=1.5, gt=0, le=600,
                           description="minimum visible time between gaps, s")
    count: int | None = Field(default=None, ge=1,
                              description="number of gaps (null: as many as fit)")

    _check_range = field_validator("gap_range")(_gap_range_ok)


def _resolve(path: str, info: ValidationInfo) -> str:
    base = (info.context or {}).get("base_dir")
    resolved = Path(path).expanduser()
    if base is not None and not resolved.is_absolute():
        resolved = Path(base) / resolved
    return str(resolved)


class SimulateData(_Strict):
    """Simulated recordings scored against the simulator's truth."""

    kind: Literal["simulate"]
    scenario: str = Field(description="simulator scenario (kfusion.simulate.SCENARIOS)")
    imu: str = Field(default="mpu9255", description="IMU profile (kfusion.profiles)")
    occlusions: OcclusionsConfig = Field(default=OcclusionsConfig())
    duration: float | None = Field(default=None, gt=0, le=3600,  # simulate.MAX_DURATION
                                   description="seconds (null: the scenario's own length)")

    @field_validator("scenario")
    @classmethod
    def _known_scenario(cls, value: str) -> str:
        names = _scenario_names()
        if value not in names:
            raise ValueError(f"unknown scenario; expected one of {sorted(names)}")
        return value

    @field_validator("imu")
    @classmethod
    def _known_imu(cls, value: str) -> str:
        if value.lower() not in IMU_PROFILES:
            raise ValueError(f"unknown IMU profile; expected one of {sorted(IMU_PROFILES)}")
        return value.lower()

    def scored_recordings(self, seed: int, *, quick: bool = False) -> list[ScoredRecording]:
        """One simulated recording for ``seed``.

        Quick mode caps the duration at :data:`QUICK_SIMULATION_S`, or keeps the configured one
        when no gap of the requested placement fits in the shorter motion."""
        if quick and (self.duration is None or self.duration > QUICK_SIMULATION_S):
            with contextlib.suppress(ValueError):
                return [simulated_recording(self.scenario, seed, imu=self.imu,
                                            occlusions=self.occlusions,
                                            duration=QUICK_SIMULATION_S)]
        return [simulated_recording(self.scenario, seed, imu=self.imu,
                                    occlusions=self.occlusions, duration=self.duration)]


def _trials_all_or_list(value: Any) -> Any:
    if isinstance(value, str):
        if value != "all":
            raise ValueError(f"expected 'all' or a list of trial keys like ['01', '21'], "
                             f"got {value!r}")
        return None
    if isinstance(value, list):
        return [f"{item:02d}" if isinstance(item, int) and not isinstance(item, bool) else item
                for item in value]
    return value


class BroadData(_Strict):
    """The real BROAD trials (mocap + IMU), with artificial gaps scored against the hidden
    mocap."""

    kind: Literal["broad"]
    trials: Annotated[list[str] | None, BeforeValidator(_trials_all_or_list)] = Field(
        default=None, description="'all' or trial keys (file-name prefixes) like ['01', '21']")
    directory: str | None = Field(default=None, description="folder of the .mat files "
                                  "(relative to the config file); null: kfusion.datasets finds it")
    mocap_step: int = Field(default=3, ge=1, le=100,
                            description="keep every n-th mocap sample (3: ~95 Hz like OptiTrack)")
    gaps: GapsConfig = Field(default=GapsConfig())

    @field_validator("trials")
    @classmethod
    def _nonempty(cls, value: list[str] | None) -> list[str] | None:
        if value is not None and not value:
            raise ValueError("expected 'all' or at least one trial key, got []")
        return value

    @field_validator("directory")
    @classmethod
    def _relative_to_config(cls, value: str | None, info: ValidationInfo) -> str | None:
        return None if value is None else _resolve(value, info)

    def trial_paths(self) -> list[Path]:
        """The ``.mat`` files named by ``trials`` (all of them for ``'all'``)."""
        from kfusion import datasets

        if self.directory is None:
            paths = datasets.broad_trials()
        else:
            paths = sorted(Path(self.directory).glob("*.mat"))
            if not paths:
                raise ValueError(f"data.directory: no .mat files in {self.directory}")
        if self.trials is None:
            return paths
        chosen = []
        for key in self.trials:
            matches = [path for path in paths if path.name.startswith(key)]
            if len(matches) != 1:
                raise ValueError(f"data.trials: trial {key!r} matches {len(matches)} files in "
                                 f"{paths[0].parent}; expected exactly one of "
                                 f"{[path.stem for path in paths]}")
            chosen.append(matches[0])
        return chosen

    def scored_recordings(self, seed: int, *, quick: bool = False) -> list[ScoredRecording]:
        """Each trial read with :func:`kfusion.readers.broad.read_broad` and cut with
        :func:`kfusion.evaluate.cut_gaps`; quick mode keeps the first trial's first
        :data:`QUICK_RECORDING_S` s."""
        from kfusion.readers.broad import read_broad

        paths = self.trial_paths()[:1] if quick else self.trial_paths()
        scored = []
        for path in paths:
            recording = read_broad(path, mocap_step=self.mocap_step)
            if quick:
                recording = first_seconds(recording, QUICK_RECORDING_S)
            scored.append(recording_with_gaps(path.stem, recording, self.gaps, seed))
        return scored


class FolderData(_Strict):
    """Recording folders (``kfusion check`` format) with artificial gaps cut where the mocap is
    valid, scored against the hidden mocap."""

    kind: Literal["folder"]
    folders: list[str] = Field(min_length=1, description="recording folders (relative to the "
                               "config file)")
    zeros_occluded: bool = Field(default=False,
                                 description="read a (0, 0, 0) mocap position as occluded")
    gaps: GapsConfig = Field(default=GapsConfig())

    @field_validator("folders")
    @classmethod
    def _relative_to_config(cls, value: list[str], info: ValidationInfo) -> list[str]:
        return [_resolve(folder, info) for folder in value]

    def scored_recordings(self, seed: int, *, quick: bool = False) -> list[ScoredRecording]:
        """Each folder read with :func:`kfusion.recording.read_recording` and cut; quick mode
        keeps the first folder's first :data:`QUICK_RECORDING_S` s."""
        from kfusion.recording import read_recording

        scored = []
        for folder in self.folders[:1] if quick else self.folders:
            recording = read_recording(folder, zero_position_means_occluded=self.zeros_occluded)
            if quick:
                recording = first_seconds(recording, QUICK_RECORDING_S)
            scored.append(recording_with_gaps(Path(folder).name, recording, self.gaps, seed))
        return scored


PartConfig = Annotated[SimulateData | BroadData | FolderData, Field(discriminator="kind")]


class CombinedData(_Strict):
    """Several data sections scored together, e.g. every simulated paper scenario in one table
    (the README's accuracy tables). Each part is labelled; its recordings are named
    ``<label>/<name>``."""

    kind: Literal["combined"]
    parts: dict[str, PartConfig] = Field(min_length=1, description="label -> data section "
                                         "(simulate, broad or folder)")

    @field_validator("parts")
    @classmethod
    def _plain_labels(cls, value: dict[str, Any]) -> dict[str, Any]:
        for label in value:
            plain_name(label)
        return value

    def scored_recordings(self, seed: int, *, quick: bool = False) -> list[ScoredRecording]:
        """Every part's recordings for ``seed``, in the order of ``parts``."""
        return [dataclasses.replace(scored, name=f"{label}/{scored.name}")
                for label, part in self.parts.items()
                for scored in part.scored_recordings(seed, quick=quick)]


DataConfig = Annotated[SimulateData | BroadData | FolderData | CombinedData,
                       Field(discriminator="kind")]
DATA_KINDS = tuple(sorted(typing.get_args(model.model_fields["kind"].annotation)[0]
                          for model in (SimulateData, BroadData, FolderData, CombinedData)))
"""The data section's ``kind`` values."""
PART_KINDS = tuple(kind for kind in DATA_KINDS if kind != "combined")
"""The ``kind`` values of a combined section's parts (no nesting)."""


class PlotsConfig(_Strict):
    """Figures written by ``kfusion run``."""

    trajectory: bool = Field(default=True, description="trajectory with gaps, per recording of "
                             "the first seed (like the paper's figures)")
    axes: list[Literal["x", "y", "z"]] = Field(default=["x", "y", "z"], min_length=1,
                                               description="axes drawn in the trajectory figure")
    window_s: float | None = Field(default=8.0, gt=0, description="seconds of trajectory shown, "
                                   "where the IMU turns fastest among windows holding a gap "
                                   "(null: all)")
    error_by_gap: bool = Field(default=True, description="per-gap error against gap length")
    metric: Literal["max_mm", "rms_mm", "mean_mm"] = Field(
        default="max_mm", description="per-gap metric of the error-by-gap figure")


class OutputConfig(_Strict):
    """Where results go."""

    directory: str | None = Field(default=None, description="output folder, relative to the "
                                  "current directory (null: kfusion-output/<name>); --out "
                                  "overrides")
    plots: PlotsConfig = Field(default=PlotsConfig())


def plain_name(value: str) -> str:
    """``value`` if it can name a folder inside the output root (``kfusion-output/<name>``):
    one path component, not ``.`` or ``..``, no path separator, drive or control character;
    ValueError otherwise, so a config name never writes outside the output folder."""
    bad = [character for character in ("/", "\\", ":", "\0") if character in value]
    if (bad or value in (".", "..") or value != value.strip()
            or any(ord(character) < 32 for character in value)):
        raise ValueError("expected a plain name (one folder name: no '/', '\\', ':', "
                         "leading or trailing spaces, control characters, '.' or '..'), "
                         f"got {short_repr(value)}")
    return value


def _seeds(value: Any) -> Any:
    if isinstance(value, int) and not isinstance(value, bool):
        if value < 1:
            raise ValueError(f"expected a positive number of seeds or a list of seeds, "
                             f"got {value}")
        return list(range(value))
    return value


def _default_methods() -> dict[str, dict[str, Any]]:
    return {name: {} for name in METHODS}


class RunConfig(_Strict):
    """One experiment: data, methods with their parameter overrides, seeds, output."""

    name: str = Field(default="experiment", min_length=1,
                      description="label (default: file name)")
    description: str = Field(default="", description="free text")
    data: DataConfig
    methods: dict[str, dict[str, Any]] = Field(
        default_factory=_default_methods, min_length=1,
        description="method name -> parameter overrides (every registered method by default)")
    seeds: Annotated[list[int], BeforeValidator(_seeds)] = Field(
        default=[0], min_length=1,
        description="random seeds (simulation, gap cutting); n means 0..n-1")
    output: OutputConfig = Field(default=OutputConfig())
    quick: bool = Field(default=False, description="shrink data for smoke tests (set by --quick)")
    engine: Literal["compiled", "filterpy"] = Field(
        default="compiled", description="Kalman filter engine: compiled (numba kernels) or "
        "filterpy (the reference); see kfusion.kalman.engines")

    @field_validator("name")
    @classmethod
    def _plain_name(cls, value: str) -> str:
        return plain_name(value)

    @field_validator("seeds")
    @classmethod
    def _unique_seeds(cls, value: list[int]) -> list[int]:
        if len(set(value)) != len(value) or min(value) < 0:
            raise ValueError(f"expected distinct non-negative seeds, got {value}")
        return value

    def output_directory(self, override: str | Path | None = None) -> Path:
        """``override`` or ``output.directory`` or ``kfusion-output/<name>``."""
        if override is not None:
            return Path(override)
        if self.output.directory is not None:
            return Path(self.output.directory)
        return DEFAULT_OUTPUT_ROOT / self.name

    def scored_recordings(self, seed: int) -> list[ScoredRecording]:
        """The recordings of this experiment for ``seed`` (quick mode shrinks them)."""
        return self.data.scored_recordings(seed, quick=self.quick)


class HeatmapConfig(_Strict):
    """A sweep heat map: ``value`` (mean over seeds and other axes) on ``rows`` x ``columns``,
    one panel per value of ``facet``."""

    rows: str
    columns: str
    value: str = Field(default="rms_mm", description=f"one of {list(METRIC_NAMES)}")
    facet: str | None = None

    @field_validator("value")
    @classmethod
    def _metric(cls, value: str) -> str:
        if value not in METRIC_NAMES:
            raise ValueError(f"unknown metric {value!r}; expected one of {list(METRIC_NAMES)}")
        return value


class SweepFile(RunConfig):
    """A sweep config file: a run config plus the grid (validated point by point after this)."""

    grid: dict[str, list[Any]] = Field(description="dotted key path (or 'method') -> values")
    heatmaps: list[HeatmapConfig] | None = Field(
        default=None, description="heat maps to draw (default: one for a two- or three-axis grid)")

    @field_validator("grid")
    @classmethod
    def _some_axis(cls, value: dict[str, list[Any]]) -> dict[str, list[Any]]:
        if not value:
            raise ValueError("expected at least one axis (dotted key path -> list of values)")
        return value


# --------------------------------------------------------------------------------------------
# validation helpers


def _scenario_names() -> tuple[str, ...]:
    from kfusion.simulate import SCENARIOS

    return tuple(SCENARIOS)


def _unwrap(annotation: Any) -> list[Any]:
    """The concrete types an annotation can hold (Annotated, Optional and unions opened)."""
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        return _unwrap(typing.get_args(annotation)[0])
    if origin is Union or origin is types.UnionType:
        return [kind for arg in typing.get_args(annotation) for kind in _unwrap(arg)]
    return [annotation]


def _model_at(model: type[BaseModel], raw: Any, parts: Sequence[str | int]
              ) -> type[BaseModel] | None:
    """The model class found by following ``parts`` from ``model`` through ``raw``."""
    current: Any = model
    node = raw
    for part in parts:
        if not (isinstance(current, tuple)
                or (isinstance(current, type) and issubclass(current, BaseModel))):
            return None
        if isinstance(current, tuple):  # a mapping of models: ``part`` is one of its keys
            annotation, current = current[0], None
        else:
            field = current.model_fields.get(str(part))
            if field is None:
                return None
            annotation = field.annotation
        node = node.get(part) if isinstance(node, Mapping) else None
        if typing.get_origin(annotation) is dict:
            current = (typing.get_args(annotation)[1],)
            continue
        candidates = [kind for kind in _unwrap(annotation)
                      if isinstance(kind, type) and issubclass(kind, BaseModel)]
        if len(candidates) > 1 and isinstance(node, Mapping):
            tagged = [kind for kind in candidates if "kind" in kind.model_fields
                      and node.get("kind") in typing.get_args(kind.model_fields["kind"].annotation)]
            candidates = tagged
        if len(candidates) != 1:
            return None
        current = candidates[0]
    return current if isinstance(current, type) and issubclass(current, BaseModel) else None


def _issues_from_validation(error: ValidationError, model: type[BaseModel], raw: Any
                            ) -> list[ConfigIssue]:
    """pydantic errors -> issues with dotted key paths of the user's file.

    pydantic's ``loc`` also holds union-member tags (``'simulate'``, ``'list[str]'``); only the
    parts that index the user's mapping are kept.
    """
    issues: list[ConfigIssue] = []
    for item in error.errors():
        loc = list(item["loc"])
        kept: list[str | int] = []
        node = raw
        for position, part in enumerate(loc):
            if isinstance(node, Mapping) and part in node:
                kept.append(part)
                node = node[part]
            elif isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
                kept.append(part)
                node = node[part]
            elif position == len(loc) - 1 and not isinstance(part, int) and (
                    item["type"] == "missing" or not isinstance(node, Mapping)):
                kept.append(part)
        path = _format_path(kept)
        kind = item["type"]
        if kind == "extra_forbidden":
            parent = _model_at(model, raw, kept[:-1])
            expected = sorted(parent.model_fields) if parent is not None else []
            issues.append(ConfigIssue(path, f"unknown key; expected one of {expected}",
                                      unknown_key=True))
        elif kind == "missing":
            issues.append(ConfigIssue(path, "required key is missing"))
        elif kind in ("union_tag_invalid", "union_tag_not_found"):
            issues.append(ConfigIssue(
                _format_path([*kept, "kind"]),
                f"expected one of {list(PART_KINDS if 'parts' in kept else DATA_KINDS)}, "
                f"got {short_repr(node.get('kind'), 40)}"
                if isinstance(node, Mapping)
                else f"expected a mapping with a kind, got {short_repr(node)}"))
        else:
            message = str(item["msg"]).removeprefix("Value error, ")
            if kept and "got " not in message:
                message += f", got {short_repr(item.get('input'))}"
            issues.append(ConfigIssue(path, message))
    # a union reports one error per member; keep the most specific ones
    unique: dict[tuple[str, str], ConfigIssue] = {}
    for issue in issues:
        unique.setdefault((issue.path, issue.message), issue)
    kept_issues = list(unique.values())
    return [issue for issue in kept_issues
            if not any(other.path.startswith(issue.path + "[") or
                       other.path.startswith(issue.path + ".")
                       for other in kept_issues if other is not issue and issue.path)]


def _parameter_class(method: str) -> type | None:
    target = PARAMETER_CLASSES.get(method)
    if target is None:
        return None
    module_name, class_name = target.split(":")
    module = importlib.import_module(module_name)
    kind = getattr(module, class_name, None)
    return kind if isinstance(kind, type) else None


def parameter_fields(method: str) -> dict[str, Any] | None:
    """Field name -> type of ``method``'s parameter dataclass (None if it has none)."""
    kind = _parameter_class(method)
    if kind is None or not dataclasses.is_dataclass(kind):
        return None
    hints = typing.get_type_hints(kind)
    return {field.name: hints.get(field.name, Any) for field in dataclasses.fields(kind)
            if field.init}


def _build_parameters(method: str, overrides: Mapping[str, Any]) -> object:
    """The method's parameter object with ``overrides``, so its own range checks run: through
    ``from_profiles`` (default profiles) where the class has one, else the constructor."""
    kind: Any = _parameter_class(method)
    if hasattr(kind, "from_profiles"):
        return kind.from_profiles(**overrides)
    return kind(**overrides)


def _takes_bool(annotation: Any) -> bool:
    """True when a field of type ``annotation`` takes true/false (``bool``, or a union with it;
    ``Any``)."""
    return annotation is bool or annotation is Any or bool in typing.get_args(annotation)


def check_methods(methods: Mapping[str, Mapping[str, Any]]
                  ) -> tuple[dict[str, dict[str, Any]], list[ConfigIssue]]:
    """Check method names and their parameter overrides; return the overrides converted to the
    fields' types (e.g. ``"1e-3"`` -> 0.001) and the issues found."""
    issues: list[ConfigIssue] = []
    converted: dict[str, dict[str, Any]] = {}
    for method, overrides in methods.items():
        if method not in METHODS:
            issues.append(ConfigIssue(f"methods.{method}", f"unknown method; expected one of "
                                      f"{sorted(METHODS)}", unknown_key=True))
            continue
        fields = parameter_fields(method)
        if fields is None:
            converted[method] = dict(overrides)
            continue
        values: dict[str, Any] = {}
        for key, value in overrides.items():
            path = f"methods.{method}.{key}"
            if key not in fields:
                issues.append(ConfigIssue(path, f"unknown parameter; expected one of "
                                          f"{sorted(fields)}", unknown_key=True))
                continue
            if isinstance(value, bool) and not _takes_bool(fields[key]):
                # pydantic's lax mode reads true as 1.0: `max_bridge_s: true` bridged 1 s
                issues.append(ConfigIssue(path, f"expected a number, got {str(value).lower()}"))
                continue
            try:
                values[key] = TypeAdapter(fields[key]).validate_python(value)
            except ValidationError as error:
                reason = str(error.errors()[0]["msg"])
                issues.append(ConfigIssue(path, f"{reason}, got {short_repr(value)}"))
            except Exception:  # an annotation pydantic cannot check: keep the value
                values[key] = value
        if len(values) == len(overrides):
            try:
                _build_parameters(method, values)
            except (ValueError, TypeError) as error:
                issues.append(ConfigIssue(f"methods.{method}", str(error)))
        converted[method] = values
    return converted, issues


def _validate_run(raw: Mapping[str, Any], *, file: str | Path | None, base_dir: Path | None,
                  model: type[RunConfig] = RunConfig) -> RunConfig:
    """Validate a run-config mapping; ConfigError naming every bad key path."""
    try:
        config = model.model_validate(raw, context={"base_dir": base_dir})
    except ValidationError as error:
        issues = _issues_from_validation(error, model, raw)
        methods = raw.get("methods")
        if isinstance(methods, Mapping) and all(isinstance(value, Mapping)
                                                for value in methods.values()):
            issues.extend(check_methods(methods)[1])
        raise ConfigError(file, issues) from None
    methods, issues = check_methods(config.methods)
    if issues:
        raise ConfigError(file, issues)
    return config.model_copy(update={"methods": methods})


# --------------------------------------------------------------------------------------------
# sweeps


@dataclass(frozen=True)
class SweepPoint:
    """One grid point: its axis values (``{"data.imu": "um7", "method": "kalman", ...}``) and the
    run config it makes, holding that single method."""

    parameters: dict[str, Any]
    config: RunConfig

    @property
    def method(self) -> str:
        return next(iter(self.config.methods))


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep: the base run config, the grid, its expanded points and heat maps."""

    base: RunConfig
    grid: dict[str, list[Any]]
    points: tuple[SweepPoint, ...]
    heatmaps: tuple[HeatmapConfig, ...]

    @property
    def axes(self) -> list[str]:
        """Grid axes in order, ``method`` included (last unless the grid placed it)."""
        return list(self.points[0].parameters) if self.points else list(self.grid)

    @property
    def name(self) -> str:
        return self.base.name

    @property
    def seeds(self) -> list[int]:
        return self.base.seeds

    def output_directory(self, override: str | Path | None = None) -> Path:
        return self.base.output_directory(override)


def _set_path(raw: dict[str, Any], path: str, value: Any) -> None:
    """Set ``raw[a][b][c] = value`` for ``path = "a.b.c"``, creating mappings on the way."""
    parts = path.split(".")
    node = raw
    for index, part in enumerate(parts[:-1]):
        child = node.get(part)
        if child is None:
            child = node[part] = {}
        if not isinstance(child, dict):
            raise ValueError(f"{'.'.join(parts[: index + 1])} is not a mapping")
        node = child
    node[parts[-1]] = value


def _grid_key_issues(grid: Mapping[str, list[Any]]) -> list[ConfigIssue]:
    issues = []
    for axis, values in grid.items():
        root = axis.split(".")[0]
        if axis != "method" and (root not in GRID_ROOTS or "." not in axis):
            issues.append(ConfigIssue(f"grid.{axis}", "expected 'method' or a dotted key path "
                                      f"starting with one of {list(GRID_ROOTS)}",
                                      unknown_key=True))
        elif not values:
            issues.append(ConfigIssue(f"grid.{axis}", "expected a non-empty list of values, "
                                      "got []"))
        elif axis == "method":
            issues.extend(ConfigIssue(f"grid.method[{index}]", f"unknown method {value!r}; "
                                      f"expected one of {sorted(METHODS)}")
                          for index, value in enumerate(values) if value not in METHODS)
    return issues


def _relabel(issue: ConfigIssue, axis: str, index: int) -> ConfigIssue | None:
    """An issue of a point with only ``axis`` set to its ``index``-th value, named by grid key."""
    if not (issue.path == axis or issue.path.startswith(axis + ".")
            or issue.path.startswith(axis + "[") or axis.startswith(issue.path + ".")):
        return None
    if issue.unknown_key:
        return ConfigIssue(f"grid.{axis}", issue.message, unknown_key=True)
    return ConfigIssue(f"grid.{axis}[{index}]" + issue.path[len(axis):]
                       if issue.path.startswith(axis) else f"grid.{axis}[{index}]",
                       issue.message)


def _expand_sweep(raw: Mapping[str, Any], file: str | Path | None, base_dir: Path | None
                  ) -> SweepConfig:
    sweep_file = typing.cast(SweepFile, _validate_run(raw, file=file, base_dir=base_dir,
                                                       model=SweepFile))
    grid = dict(sweep_file.grid)
    issues = _grid_key_issues(grid)
    axes = set(grid) | {"method"}
    for index, heatmap in enumerate(sweep_file.heatmaps or []):
        for role in ("rows", "columns", "facet"):
            axis = getattr(heatmap, role)
            if axis is not None and axis not in axes:
                issues.append(ConfigIssue(f"heatmaps[{index}].{role}", f"{axis!r} is not a grid "
                                          f"axis; expected one of {sorted(axes)}"))
    if issues:
        raise ConfigError(file, issues)
    base_raw = {key: value for key, value in raw.items() if key not in ("grid", "heatmaps")}
    base = _validate_run(base_raw, file=file, base_dir=base_dir)
    data_axes = [axis for axis in grid if axis != "method"]

    def point_raw(assignment: Mapping[str, Any]) -> dict[str, Any]:
        point = json.loads(json.dumps(base_raw))
        for axis, value in assignment.items():
            try:
                _set_path(point, axis, value)
            except ValueError as error:
                raise ConfigError(file, [ConfigIssue(f"grid.{axis}", str(error))]) from None
        return point

    # each value alone first, so a bad value is reported by its grid key and index
    for axis in data_axes:
        for index, value in enumerate(grid[axis]):
            try:
                _validate_run(point_raw({axis: value}), file=file, base_dir=base_dir)
            except ConfigError as error:
                relabelled = [_relabel(issue, axis, index) or issue for issue in error.issues]
                raise ConfigError(file, relabelled) from None
    points: list[SweepPoint] = []
    for values in itertools.product(*(grid[axis] for axis in data_axes)):
        assignment = dict(zip(data_axes, values, strict=True))
        try:
            config = _validate_run(point_raw(assignment), file=file, base_dir=base_dir)
        except ConfigError as error:
            where = ", ".join(f"{axis}={short_repr(value, 30)}"
                              for axis, value in assignment.items())
            raise ConfigError(file, [ConfigIssue(f"grid point ({where}): {issue.path}",
                                                 issue.message) for issue in error.issues]
                              ) from None
        for method in grid.get("method", list(config.methods)):
            single = config.model_copy(update={"methods": {method: config.methods.get(method,
                                                                                      {})}})
            parameters = {**assignment, "method": method}
            if "method" in grid:  # the user's axis order
                parameters = {axis: parameters[axis] for axis in grid}
            points.append(SweepPoint(parameters=parameters, config=single))
    if "method" in grid:  # enumerate in the grid's order, the first axis slowest
        position = {axis: {json.dumps(value, default=str): index
                           for index, value in enumerate(grid[axis])} for axis in grid}
        points.sort(key=lambda point: [position[axis][json.dumps(point.parameters[axis],
                                                                 default=str)]
                                       for axis in grid])
    counts = {axis: len({json.dumps(point.parameters[axis], default=str) for point in points})
              for axis in points[0].parameters}
    heatmaps = tuple(sweep_file.heatmaps) if sweep_file.heatmaps is not None else \
        default_heatmaps(counts)
    return SweepConfig(base=base, grid=grid, points=tuple(points), heatmaps=heatmaps)


def default_heatmaps(value_counts: Mapping[str, int]) -> tuple[HeatmapConfig, ...]:
    """RMS heat maps over the axes with more than one value (``value_counts``: axis -> number of
    distinct values): two -> rows x columns, three -> one panel per value of the last; other
    counts -> none."""
    varying = [axis for axis, count in value_counts.items() if count > 1]
    if len(varying) == 2:
        return (HeatmapConfig(rows=varying[0], columns=varying[1]),)
    if len(varying) == 3:
        return (HeatmapConfig(rows=varying[0], columns=varying[1], facet=varying[2]),)
    return ()


# --------------------------------------------------------------------------------------------
# loading


def read_yaml(path: str | Path) -> dict[str, Any]:
    """The YAML mapping in ``path`` (read by :func:`kfusion.guards.load_yaml`: bounded, UTF-8,
    no duplicate keys); ConfigError (file, line) for unreadable or non-mapping files."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        raw = load_yaml(path)
    except YamlError as error:
        reason = f"invalid YAML at {error.reason}" if error.syntax else error.reason
        raise ConfigError(path, [ConfigIssue("", reason)]) from None
    if not isinstance(raw, dict):
        raise ConfigError(path, [ConfigIssue("", "expected a mapping of keys (data, methods, "
                                             f"...), got {type(raw).__name__}")])
    return raw


def parse_config(raw: Mapping[str, Any], *, file: str | Path | None = None,
                 base_dir: str | Path | None = None, quick: bool = False
                 ) -> RunConfig | SweepConfig:
    """Validate a config mapping: a :class:`SweepConfig` if it has ``grid``, else a
    :class:`RunConfig`. ``base_dir`` anchors relative paths; ``quick`` shrinks the data
    (first seed, short recordings, :data:`QUICK_GRID_VALUES` values per grid axis)."""
    raw = dict(raw)
    if "name" not in raw and file is not None:
        raw["name"] = Path(file).stem
    if quick:
        raw["quick"] = True
    anchor = Path(base_dir) if base_dir is not None else (
        Path(file).resolve().parent if file is not None else None)
    if "grid" in raw:
        if quick:
            raw = _quick_sweep(raw)
        return _expand_sweep(raw, file, anchor)
    config = _validate_run(raw, file=file, base_dir=anchor)
    if quick:
        config = config.model_copy(update={"seeds": config.seeds[:1]})
    return config


def _quick_sweep(raw: dict[str, Any]) -> dict[str, Any]:
    grid = raw["grid"]
    if isinstance(grid, dict):
        raw["grid"] = {axis: values[:QUICK_GRID_VALUES] if isinstance(values, list) else values
                       for axis, values in grid.items()}
    seeds = raw.get("seeds", [0])
    raw["seeds"] = [0] if isinstance(seeds, int) else seeds[:1] if isinstance(seeds, list) \
        else seeds
    return raw


def load_config(path: str | Path, *, quick: bool = False) -> RunConfig | SweepConfig:
    """Read and validate a config file (run or sweep); ConfigError naming file and key path."""
    return parse_config(read_yaml(path), file=path, quick=quick)


def load_run_config(path: str | Path, *, quick: bool = False) -> RunConfig:
    """A run config; ConfigError if the file is a sweep config."""
    config = load_config(path, quick=quick)
    if isinstance(config, SweepConfig):
        raise ConfigError(path, [ConfigIssue("grid", "this is a sweep config (it has a grid); "
                                             "run it with 'kfusion sweep'")])
    return config


def load_sweep_config(path: str | Path, *, quick: bool = False) -> SweepConfig:
    """A sweep config; ConfigError if the file has no grid."""
    config = load_config(path, quick=quick)
    if not isinstance(config, SweepConfig):
        raise ConfigError(path, [ConfigIssue("grid", "required key is missing (a sweep config "
                                             "is a run config plus a grid of values)")])
    return config


def config_directory() -> Path:
    """The ``configs/`` folder: in the current directory or a parent of it, else beside the
    checkout that holds this package."""
    for base in (Path.cwd(), Path(__file__).resolve().parent):
        for parent in (base, *base.parents):
            if (parent / "configs").is_dir() and any((parent / "configs").glob("*.yaml")):
                return parent / "configs"
    raise ValueError("configs/ folder not found in the current directory, its parents, or "
                     "beside the kfusion checkout")


def find_config(name: str) -> Path:
    """Path of the bundled config ``name`` (``"circle"`` or ``"circle.yaml"``)."""
    directory = config_directory()
    path = directory / (name if name.endswith((".yaml", ".yml")) else f"{name}.yaml")
    if not path.is_file():
        names = sorted(p.stem for p in directory.glob("*.yaml"))
        raise ValueError(f"config {name!r} not found in {directory}; expected one of {names}")
    return path


def notebook_quick() -> bool:
    """True when :data:`NOTEBOOK_QUICK_VARIABLE` is set to a true value (notebooks then run on
    small data)."""
    return os.environ.get(NOTEBOOK_QUICK_VARIABLE, "").lower() in ("1", "true", "yes")


# --------------------------------------------------------------------------------------------
# data helpers


def first_seconds(recording: Recording, seconds: float) -> Recording:
    """The recording cut to samples with ``t <= t0 + seconds`` on the mocap clock (t0: first
    sample of either sensor; IMU stamps mapped by the recording's clock model, which is kept)."""
    info = recording.info
    imu_t = imu_time_to_mocap(recording.imu.t, info.imu_time_offset, info.imu_clock_drift_ppm)
    start = min(imu_t[0], recording.mocap.t[0])
    imu_keep = imu_t <= start + seconds
    mocap_keep = recording.mocap.t <= start + seconds
    imu = ImuSamples(recording.imu.t[imu_keep], recording.imu.accelerometer[imu_keep],
                     recording.imu.gyroscope[imu_keep])
    mocap = MocapFrames(recording.mocap.t[mocap_keep], recording.mocap.position[mocap_keep],
                        recording.mocap.quaternion[mocap_keep])
    return dataclasses.replace(recording, imu=imu, mocap=mocap)


def simulated_recording(scenario: str, seed: int, *, imu: str = "mpu9255",
                        occlusions: OcclusionsConfig | None = None,
                        duration: float | None = None) -> ScoredRecording:
    """A simulated recording scored against the simulator's truth: the one builder of simulated
    data sets (configs, benchmarks, tests, ``kfusion demo``). Named
    ``<scenario>/<imu>/seed<seed>``; ``duration`` s (None: the scenario's own length)."""
    from kfusion.simulate import OcclusionSpec, simulate

    gaps = OcclusionsConfig() if occlusions is None else occlusions
    simulation = simulate(scenario, seed=seed, imu=imu, duration=duration,
                          occlusions=OcclusionSpec(gap_range=gaps.gap_range,
                                                   placement=gaps.placement,
                                                   spacing=gaps.spacing, count=gaps.count))
    return ScoredRecording(name=f"{scenario}/{imu}/seed{seed}",
                           recording=simulation.recording,
                           truth_position=simulation.truth.position,
                           gap_mask=simulation.truth.occluded)


def recording_with_gaps(name: str, recording: Recording, gaps: GapsConfig | None = None,
                        seed: int = 0) -> ScoredRecording:
    """A real recording with artificial gaps cut where its mocap is valid, scored against the
    hidden mocap (:func:`kfusion.evaluate.cut_gaps`): the one builder of real data sets. Named
    ``<name>/seed<seed>``.

    The gap pattern comes from a generator seeded by ``(seed, crc32(name))`` (each recording
    its own pattern, reproducible whatever the other recordings are), or by ``seed`` alone with
    ``gaps.seeding == "shared"``."""
    from kfusion.evaluate import cut_gaps

    gaps = GapsConfig() if gaps is None else gaps
    rng = (np.random.default_rng(seed) if gaps.seeding == "shared"
           else np.random.default_rng([seed, zlib.crc32(name.encode())]))
    gapped = cut_gaps(recording, rng=rng, gap_range=gaps.gap_range, spacing=gaps.spacing,
                      count=gaps.count)
    return ScoredRecording(name=f"{name}/seed{seed}", recording=gapped.recording,
                           truth_position=gapped.truth_position, gap_mask=gapped.gap_mask)


def fingerprint(value: Any) -> str:
    """12 hex digits of SHA-1 over the canonical JSON of ``value`` (stable across runs)."""
    text = json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:12]
