"""Guards at kfusion's edges: bounded YAML reading, atomic file writing, short value descriptions
for messages, and plain-array checks.

* :func:`load_yaml` / :func:`load_yaml_text`: every YAML kfusion reads (``recording.yaml``,
  configs, :meth:`kfusion.tracker.Tracker.from_yaml`, ``--set`` values) goes through one loader
  that refuses files over :data:`MAX_YAML_BYTES`, text that is not UTF-8, a key given twice, and
  aliases whose expansion exceeds :data:`MAX_YAML_NODES` nodes or :data:`MAX_YAML_DEPTH` levels
  (a 410-byte "billion laughs" file otherwise expands to gigabytes when read). Failures raise
  :class:`YamlError`, one line naming the file.
* :func:`atomic_write`: a file kfusion writes for a user appears complete or not at all: it is
  written to a temporary file in the same folder, flushed to disk, then renamed over the target
  with ``os.replace``. A failed write (full disk, interrupted) leaves the previous file intact.
* :func:`short_repr`: a value for an error message, never longer than ``limit`` characters and
  never built by printing a whole huge value (a 400-digit integer, a nested list).
* :func:`finite_float`: the argparse type of every number option of the command line; ``nan``
  and ``inf`` are refused there (``--start nan`` printed from the start, ``--start inf`` nothing).
* :func:`refuse_masked`: numpy masked arrays silently lose their mask in ``np.asarray``; they are
  refused with a message saying to mark missing values with NaN.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import reprlib
import tempfile
from collections.abc import Callable
from numbers import Real
from pathlib import Path
from typing import Any, Final

import numpy as np
import yaml

MAX_YAML_BYTES: Final = 1_000_000
"""Largest YAML file read, bytes (kfusion's files are a few kB)."""
MAX_YAML_NODES: Final = 100_000
"""Most nodes a YAML document may hold once every alias is expanded."""
MAX_YAML_DEPTH: Final = 64
"""Deepest nesting of YAML collections."""
MESSAGE_VALUE_CHARS: Final = 60
"""Default length limit of a value shown in an error message, characters."""


# --------------------------------------------------------------------------------------------
# short descriptions of values


class _ShortRepr(reprlib.Repr):
    """reprlib with a limit on integer digits that never formats the whole integer."""

    def __init__(self) -> None:
        super().__init__()
        self.maxlevel = 3
        self.maxlist = self.maxtuple = self.maxset = self.maxdict = 6
        self.maxstring = 40
        self.maxother = 40

    def repr_int(self, x: int, level: int) -> str:
        if x.bit_length() <= 64:
            return repr(x)
        # 2^(b-1) <= |x| < 2^b: the digit count is one of two values; one power of ten decides
        digits = int((x.bit_length() - 1) * math.log10(2)) + 1
        if abs(x) >= 10**digits:
            digits += 1
        return f"<an integer of {digits} digits>"


_SHORT = _ShortRepr()


def short_repr(value: Any, limit: int = MESSAGE_VALUE_CHARS) -> str:
    """``repr(value)`` cut to at most ``limit`` characters (``...`` marks a cut); containers show
    their first items only and huge integers their number of digits."""
    try:
        text = _SHORT.repr(value)
    except Exception:  # a value whose repr fails: say what it is
        text = f"<{type(value).__name__}>"
    text = text.replace("\n", " ")
    return text if len(text) <= limit else text[: max(limit - 3, 1)] + "..."


def real_number(value: object) -> float | None:
    """``value`` as a float when it is a real number (``bool`` excluded), else None. An integer
    too large for a float becomes +-inf (``float()`` would raise OverflowError)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (Real, np.integer,
                                                                     np.floating)):
        return None
    try:
        return float(value)  # type: ignore[arg-type]
    except OverflowError:
        return math.inf if value > 0 else -math.inf  # type: ignore[operator]


# --------------------------------------------------------------------------------------------
# arrays


def finite_float(text: str) -> float:
    """``float(text)`` for an argparse option, refusing what is not a finite number
    (argparse then prints ``argument --start: expected a finite number, got 'nan'``, exit 2)."""
    import argparse

    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {short_repr(text)}")
    return value


def refuse_masked(where: str, value: object) -> None:
    """ValueError when ``value`` is a numpy masked array (``np.asarray`` would drop its mask
    and read the hidden values as data)."""
    if isinstance(value, np.ma.MaskedArray):
        raise ValueError(f"{where}: expected a plain array or sequence (NaN marks a missing "
                         "value), got a masked array (numpy.ma); pass value.filled(np.nan)")


# --------------------------------------------------------------------------------------------
# YAML


class YamlError(ValueError):
    """A YAML file or text cannot be read. ``str()`` is ``FILE: REASON`` on one line.

    Attributes:
        file: the file (or a label such as ``--set KEY``).
        reason: what is wrong, one line; for a syntax error it starts ``line L, column C:``.
        syntax: True when the text is not valid YAML (as opposed to too large, too deep, not
            UTF-8).
    """

    def __init__(self, file: str | Path, reason: str, *, syntax: bool = False) -> None:
        self.file = str(file)
        self.reason = reason
        self.syntax = syntax
        super().__init__(f"{self.file}: {reason}")


class _BoundedLoader(yaml.SafeLoader):
    """SafeLoader that refuses a key given twice in one mapping."""


def _construct_mapping(loader: yaml.SafeLoader, node: yaml.MappingNode, deep: bool = False
                       ) -> dict[Any, Any]:
    loader.flatten_mapping(node)  # type: ignore[no-untyped-call]  # resolve '<<' merge keys
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
        with contextlib.suppress(TypeError):  # an unhashable key fails later with its own error
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {short_repr(key, 40)}", key_node.start_mark)
            seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_BoundedLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
# YAML 1.2 floats: PyYAML follows YAML 1.1, where `1e-3` (no dot) is a string, so a noise
# density or clock offset written that way was refused as text. Dotted floats, `.inf` and
# `.nan` resolve as before.
_BoundedLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def _expanded_size(node: yaml.Node, file: str | Path) -> int:
    """Number of nodes in the document once every alias is expanded, computed on the node graph
    (an alias is the same node object as its anchor) with each node's size memoised, so a bomb
    is measured without expanding it. YamlError past the limits or for a recursive alias."""
    sizes: dict[int, int] = {}
    open_nodes: set[int] = set()

    def size(current: yaml.Node, depth: int) -> int:
        key = id(current)
        if key in sizes:
            return sizes[key]
        if depth > MAX_YAML_DEPTH:
            raise YamlError(file, f"nested deeper than {MAX_YAML_DEPTH} levels")
        if key in open_nodes:
            raise YamlError(file, "an alias refers to a collection containing it (recursive "
                            "alias); expected plain data")
        total = 1
        if isinstance(current, (yaml.SequenceNode, yaml.MappingNode)):
            open_nodes.add(key)
            children = (current.value if isinstance(current, yaml.SequenceNode)
                        else [item for pair in current.value for item in pair])
            for child in children:
                total += size(child, depth + 1)
                if total > MAX_YAML_NODES:
                    raise YamlError(file, f"aliases expand to more than {MAX_YAML_NODES} "
                                    "values; expected a small file of plain data")
            open_nodes.discard(key)
        sizes[key] = total
        return total

    return size(node, 0)


def _syntax_error(file: str | Path, error: yaml.YAMLError) -> YamlError:
    if isinstance(error, yaml.MarkedYAMLError):
        mark = error.problem_mark or error.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = str(error.problem or error.context or "invalid YAML").replace("\n", " ")
        return YamlError(file, where + problem[:200], syntax=True)
    return YamlError(file, str(error).replace("\n", " ")[:200], syntax=True)


def load_yaml_text(text: str, file: str | Path) -> Any:
    """The data in YAML ``text`` (safe types only), bounded as described in the module
    docstring; ``file`` names the source in errors. Raises :class:`YamlError`."""
    try:
        # (the reader checks the characters as it is built: a raw control character raises
        # a ReaderError here)
        loader = _BoundedLoader(text)
    except yaml.YAMLError as error:
        raise _syntax_error(file, error) from None
    try:
        node = loader.get_single_node()  # type: ignore[no-untyped-call]
        if node is None:
            return None
        _expanded_size(node, file)
        return loader.construct_document(node)  # type: ignore[no-untyped-call]
    except yaml.YAMLError as error:
        raise _syntax_error(file, error) from None
    except RecursionError:
        raise YamlError(file, f"nested deeper than {MAX_YAML_DEPTH} levels") from None
    finally:
        loader.dispose()  # type: ignore[no-untyped-call]


def load_yaml(path: str | Path, *, label: str | Path | None = None) -> Any:
    """The data in the YAML file ``path`` (see :func:`load_yaml_text`). ``label`` names the file
    in errors (default: the path as given). FileNotFoundError when it does not exist."""
    path = Path(path)
    name = path if label is None else label
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file not found")
    size = path.stat().st_size
    if size > MAX_YAML_BYTES:
        raise YamlError(name, f"file is {size} bytes; expected a YAML file of at most "
                        f"{MAX_YAML_BYTES} bytes")
    data = path.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        line = data.count(b"\n", 0, error.start) + 1
        raise YamlError(name, f"not UTF-8 text (byte 0x{data[error.start]:02x} on line {line}); "
                        "expected a UTF-8 YAML file") from None
    return load_yaml_text(text, name)


# --------------------------------------------------------------------------------------------
# atomic writing


def _new_file_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def refuse_overwriting(out: str | Path, inputs: list[Path], option: str = "--out") -> None:
    """ValueError when ``out`` is one of the existing files ``inputs`` (the same file, by inode:
    links and other spellings of its path included): an output must never replace what the
    command read. An atomic write keeps a previous output whole, not an input: ``kfusion track
    DIR --out DIR/mocap.csv`` replaced the recording's mocap with the track and exited 0."""
    target = Path(out)
    for source in inputs:
        if source.is_file() and target.exists() and os.path.samefile(target, source):
            raise ValueError(f"{option} {out}: is {source}, an input of this run; expected "
                             "another file (an output never replaces its input)")


def atomic_write(path: str | Path, write: Callable[[Path], object]) -> Path:
    """Write ``path`` all at once: ``write(temporary_path)`` fills a temporary file in the same
    folder, which is flushed to disk and renamed over ``path`` (``os.replace``). The folder is
    created if needed. Returns ``path``.

    On any failure the temporary file is removed and ``path`` keeps its previous content (or
    stays absent). A failed write raises OSError naming ``path``; ``path`` naming a folder is a
    ValueError.
    """
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path}: is a folder; expected the path of a file to write")
    path.parent.mkdir(parents=True, exist_ok=True)
    descriptor, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(descriptor)
    temporary = Path(name)
    try:
        write(temporary)
        with open(temporary, "rb+") as handle:
            os.fsync(handle.fileno())
        mode = path.stat().st_mode & 0o777 if path.is_file() else _new_file_mode()
        os.chmod(temporary, mode)
        os.replace(temporary, path)
    except OSError as error:
        with contextlib.suppress(OSError):
            temporary.unlink()
        reason = error.strerror or str(error)
        raise OSError(error.errno, f"cannot write ({reason}); any previous file is unchanged",
                      str(path)) from error
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """:func:`atomic_write` of UTF-8 ``text``."""
    return atomic_write(path, lambda temporary: temporary.write_text(text, encoding="utf-8"))
