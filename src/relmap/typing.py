"""Array type aliases used in relmap's signatures, and the base of relmap's options.

Shapes are written in docstrings as ``(..., 3)``: leading batch axes, then the trailing axes the
function works on.
"""

from __future__ import annotations

import enum
from typing import TypeAlias, TypeVar

import numpy as np
import numpy.typing as npt

from relmap.errors import ParameterError

__all__ = ["ArrayLike", "FloatArray", "IntArray", "Option", "SeedLike"]

#: A float64 array (any shape; the docstring states which).
FloatArray = npt.NDArray[np.float64]

#: An int64 array of indices.
IntArray = npt.NDArray[np.int64]

#: Anything numpy can turn into a float array.
ArrayLike = npt.ArrayLike

#: What relmap accepts wherever randomness is drawn: a Generator, a seed, or None (fresh entropy).
#: Written as a string, so that importing relmap's modules does not import ``numpy.random``
#: (≈ 25 ms; it is imported where randomness is first drawn).
SeedLike: TypeAlias = "np.random.Generator | int | None"


_O = TypeVar("_O", bound="Option")


class Option(str, enum.Enum):
    """The base of relmap's options: one enum per option, defined once, next to what it chooses.

    A member compares and hashes as its string value, so callers pass either
    (``associate=Association.JCBB`` or ``associate="jcbb"``); :meth:`parse` turns either into the
    member, or raises :class:`relmap.errors.ParameterError` listing the choices.
    """

    def __str__(self) -> str:
        return str(self.value)

    @classmethod
    def choices(cls) -> list[str]:
        """The values, in order (e.g. a command-line option's choices)."""
        return [str(member.value) for member in cls]

    @classmethod
    def parse(cls: type[_O], value: object, name: str) -> _O:
        """The member of ``value`` (a member or its value); ``name`` is the argument's name."""
        try:  # a dict look-up: calling the enum costs microseconds, and options come every step
            return cls._value2member_map_[value]  # type: ignore[return-value]
        except (KeyError, TypeError):  # (TypeError: an unhashable value)
            choices = ", ".join(repr(m.value) for m in cls)
            raise ParameterError(f"{name} must be one of {choices}; got {value!r}") from None
