"""The relmap exception hierarchy.

Every error relmap raises on purpose is a :class:`RelmapError`; each kind of bad input has its
own subclass, so callers can catch exactly what they mean to handle. Messages name what was wrong
(which argument, which batch element, which file and line).
"""

from __future__ import annotations

__all__ = [
    "CovarianceError",
    "DisconnectedError",
    "FileFormatError",
    "FrameError",
    "InconsistentMapError",
    "InconsistentMergeError",
    "IrreducibleNetworkError",
    "NonFiniteError",
    "NotPositiveSemidefiniteError",
    "NotSymmetricError",
    "NumericalError",
    "ParameterError",
    "RelmapError",
    "ShapeError",
    "SolverError",
    "UnknownATError",
    "UnknownFrameError",
]


class RelmapError(Exception):
    """Base class of every error relmap raises on purpose."""


class ShapeError(RelmapError, ValueError):
    """An array has the wrong shape (e.g. a mean that is not ``(..., 3)``)."""


class NonFiniteError(RelmapError, ValueError):
    """An input holds NaN or infinity."""


class ParameterError(RelmapError, ValueError):
    """A scalar parameter is outside its domain (a probability not in (0, 1), a step <= 0, ...)."""


class CovarianceError(RelmapError, ValueError):
    """A covariance matrix is not a valid covariance (base of the two cases below)."""


class NotSymmetricError(CovarianceError):
    """A covariance matrix is not symmetric beyond the stated tolerance."""


class NotPositiveSemidefiniteError(CovarianceError):
    """A covariance matrix has a negative eigenvalue beyond the stated tolerance."""


class InconsistentMergeError(RelmapError, ValueError):
    """Parallel ATs disagree along a direction that all of them claim to know exactly.

    Merging (Eqs. 8-10) weighs each AT by its uncertainty; along a direction where every AT has
    zero variance there is nothing to weigh, so the means must already agree there.
    """


class UnknownFrameError(RelmapError, KeyError):
    """A frame that is not in the relational map."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


#: The name the relational-map layer uses for a frame that is not in the map (an id unknown to
#: a map, a solution or a file).
FrameError = UnknownFrameError


class NumericalError(RelmapError, ArithmeticError):
    """A computation left the range of floating point (an overflow to infinity or NaN) on
    inputs that were finite: the message names the step."""


class UnknownATError(RelmapError, KeyError):
    """An AT name that is not in the relational map."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class DisconnectedError(RelmapError, ValueError):
    """A query between frames that no chain of ATs connects."""


class IrreducibleNetworkError(RelmapError, ValueError):
    """The paper's reduction (with Delta-Y) cannot reduce the network to one AT (§5).

    ``remaining`` holds the expressions of the ATs left in the irreducible loop.
    """

    def __init__(self, message: str, remaining: tuple[str, ...] = ()) -> None:
        self.remaining = remaining
        super().__init__(message)


class InconsistentMapError(RelmapError, ValueError):
    """Exactly known ATs (zero variance) that contradict each other around a loop."""


class SolverError(RelmapError, RuntimeError):
    """The joint (optimal) estimate failed: no convergence, or an unconstrained direction."""


class FileFormatError(RelmapError, ValueError):
    """A file is malformed; the message names the file and, where known, the line or entry."""

    def __init__(self, path: object, message: str, line: int | None = None) -> None:
        self.path = str(path)
        self.line = line
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")
