"""Named slots of a parameter array: the one numbering scheme of every family.

Runtime scalars reach a Taichi kernel in a small float64 ndarray (a closure constant would
recompile the kernel per value). `Slots` numbers the names in the order given, so no module
numbers slots by hand: with `P = Slots("DT", "A", "C")`, a kernel reads `prm[P.A]` (a
Python int, so a compile-time index) and the host writes `P.pack(DT=0.01, A=1.0, C=0.0)`.
A block of several slots (`Slots(..., LEAD=30)`) takes the attribute of its first slot.
"""

import numpy as np


class Slots:
    """Slot indices by name (`self.NAME`), in declaration order, and `size` in all."""

    def __init__(self, *names: str, **blocks: int):
        self.size = 0
        self._index: dict[str, int] = {}
        for name in names:
            self._add(name, 1)
        for name, width in blocks.items():
            self._add(name, width)

    def _add(self, name: str, width: int) -> None:
        if name in self._index or hasattr(self, name):
            raise ValueError(f"slot name {name!r} declared twice or reserved")
        self._index[name] = self.size
        setattr(self, name, self.size)
        self.size += width

    def pack(self, **values: float) -> np.ndarray:
        """The parameter array with the named slots set and every other slot zero."""
        prm = np.zeros(self.size)
        for name, value in values.items():
            prm[self._index[name]] = value
        return prm
