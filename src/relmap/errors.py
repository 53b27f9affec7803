"""The relmap exception hierarchy.

Every error relmap raises on purpose is a :class:`RelmapError`; each kind of bad input has its
own subclass, so callers can catch exactly what they mean to handle. Messages name what was wrong
(which argument, which batch element, which file and line).
"""

from __future__ import annotations

__all__ = [
    "ArgumentTypeError",
    "ChunkError",
    "ClusterError",
    "CovarianceError",
    "DisconnectedError",
    "DuplicateNameError",
    "FileFormatError",
    "FrameError",
    "InconsistentMapError",
    "InconsistentMergeError",
    "IrreducibleNetworkError",
    "NonFiniteError",
    "NotNumericError",
    "NotPositiveSemidefiniteError",
    "NotSymmetricError",
    "NumericalError",
    "OutputError",
    "ParameterError",
    "RelmapError",
    "ShapeError",
    "SolverError",
    "UnknownATError",
    "UnknownFrameError",
]


def _shorten(path: str, limit: int = 160) -> str:
    """A path as shown in a message: a very long one elided in the middle."""
    return path if len(path) <= limit else f"{path[:100]}…{path[-40:]} ({len(path)} characters)"


class RelmapError(Exception):
    """Base class of every error relmap raises on purpose."""


class ShapeError(RelmapError, ValueError):
    """An array has the wrong shape (e.g. a mean that is not ``(..., 3)``)."""


class NotNumericError(RelmapError, TypeError):
    """An input that should hold real numbers does not: text, a mapping, None, objects,
    booleans or complex numbers."""


class ArgumentTypeError(RelmapError, TypeError):
    """An argument of the wrong kind (an integer where an AT is expected, ...)."""


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


class DuplicateNameError(RelmapError, ValueError):
    """A name (of an AT, a group) that is already taken."""


class NumericalError(RelmapError, ArithmeticError):
    """relmap's own arithmetic left the floating-point range (overflow to inf, or NaN) on valid
    input: the message names the operation. Nothing non-finite is ever returned as a result."""


class OutputError(RelmapError, OSError):
    """An output (a file, a folder, a device) cannot be written; the message names it and why.

    Raised before any work when the destination is checked
    (:func:`relmap.io.atomic.check_writable`), and when writing fails.
    """

    def __init__(self, path: object, message: str) -> None:
        self.path = str(path)
        super().__init__(f"{_shorten(self.path)}: {message}")

    def __str__(self) -> str:  # OSError would format its arguments
        return str(self.args[0]) if self.args else ""


class SolverError(RelmapError, RuntimeError):
    """The joint (optimal) estimate failed: no convergence, or an unconstrained direction."""


class FileFormatError(RelmapError, ValueError):
    """A file is malformed; the message names the file and, where known, the line or entry."""

    def __init__(self, path: object, message: str, line: int | None = None) -> None:
        self.path = str(path)
        self.line = line
        shown = _shorten(self.path)
        where = f"{shown}:{line}" if line is not None else shown
        super().__init__(f"{where}: {message}")


class ClusterError(RelmapError, RuntimeError):
    """A Dask cluster cannot do the work: the scheduler is unreachable, no worker is there, or
    the workers lack a package relmap needs (the message names it)."""


class ChunkError(RelmapError, RuntimeError):
    """A chunk of a Monte Carlo run or of a study raised; the message names the chunk (its
    block or parameters) and the seed that reproduces it, then the original error."""

    def __init__(self, message: str, *, block: int | None = None, seed: object = None) -> None:
        super().__init__(message)
        self.block = block
        self.seed = seed

    def __reduce__(self) -> tuple[object, ...]:  # travels from a Dask worker to the client
        return (_chunk_error, (str(self), self.block, self.seed))


def _chunk_error(message: str, block: int | None, seed: object) -> ChunkError:
    return ChunkError(message, block=block, seed=seed)
