"""The position filter's state layout, composed from named blocks.

The state is a concatenation of blocks, each a 3-vector::

    position       p (m, global frame, IMU point)
    velocity       v (m/s, global frame)
    bias           b (m/s^2, IMU frame: accelerometer bias)
    lever_arm      l (m, body frame), only when the lever arm is estimated

:data:`BASE_LAYOUT` (9 states) and :data:`LEVER_LAYOUT` (12) are the two the filter uses. Adding a
state (a clock offset, say) is one local change: a block here, and the model rows that use it.
Every index elsewhere (:mod:`kfusion.kalman.model`, the filterpy engine and the compiled one)
comes from a layout, never a literal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

BlockSpec = tuple[str, int]


@dataclass(frozen=True)
class StateLayout:
    """Blocks ``(name, size)`` in state order.

    Attributes:
        blocks: the blocks, e.g. ``(("position", 3), ("velocity", 3), ("bias", 3))``.
    """

    blocks: tuple[BlockSpec, ...]

    def __post_init__(self) -> None:
        names = [name for name, _ in self.blocks]
        if len(set(names)) != len(names):
            raise ValueError(f"StateLayout: expected distinct block names, got {names}")
        for name, size in self.blocks:
            if size <= 0:
                raise ValueError(f"StateLayout: block {name!r} expected a positive size, "
                                 f"got {size}")

    @property
    def size(self) -> int:
        """Number of states n."""
        return sum(size for _, size in self.blocks)

    def has(self, name: str) -> bool:
        """True when the layout has block ``name``."""
        return any(block == name for block, _ in self.blocks)

    def start(self, name: str) -> int:
        """Index of the first state of block ``name``."""
        offset = 0
        for block, size in self.blocks:
            if block == name:
                return offset
            offset += size
        raise ValueError(f"StateLayout: no block {name!r}; expected one of "
                         f"{[block for block, _ in self.blocks]}")

    def slice(self, name: str) -> slice:
        """The states of block ``name`` as a slice of x."""
        start = self.start(name)
        size = dict(self.blocks)[name]
        return slice(start, start + size)

    def with_block(self, name: str, size: int = 3) -> StateLayout:
        """This layout with one more block at the end."""
        return StateLayout(self.blocks + ((name, size),))


BASE_LAYOUT: Final = StateLayout((("position", 3), ("velocity", 3), ("bias", 3)))
"""``[p, v, b]``: 9 states."""
LEVER_LAYOUT: Final = BASE_LAYOUT.with_block("lever_arm")
"""``[p, v, b, l]``: 12 states (lever arm estimated)."""


def layout_for(estimate_lever_arm: bool) -> StateLayout:
    """:data:`LEVER_LAYOUT` when the lever arm is estimated, else :data:`BASE_LAYOUT`."""
    return LEVER_LAYOUT if estimate_lever_arm else BASE_LAYOUT
