"""What :class:`relmap.AT` (SE(2)) and :class:`relmap.AT3` (SE(3)) share: an immutable batch of
uncertain poses, and the checks every operation on them makes.

An :class:`UncertainPose` holds a mean in its pose :attr:`~UncertainPose.group` (points of shape
``group.point_shape``: ``(3,)`` vectors for SE(2), ``(4, 4)`` matrices for SE(3)) and a
covariance ``(dof, dof)`` in that group's chart (the translation first, in the parent frame), each
with the same leading batch axes. The base does what is the same for both: storage (read-only
views), pickling, the identity, stacking, indexing and iterating the batch axes, sampling through
the chart (``group.plus``), standard deviations, and the confidence ellipse of the horizontal
position (Appendix A). It states, and never calls, the four operations each kind writes in its
own module — ``_compound``, ``_reverse``, ``_merge``, ``_chain`` —, which the free functions of
:mod:`relmap.uncertain.algebra` (``compound``, ``reverse``, ``merge``, ``compound_chain``) call
after the shared checks, and the kind's ``a @ b`` and ``a.reverse()`` call directly: no function
chooses a kind by ``isinstance``, and nothing here calls up into a kind.

The helpers below validate once, at the edge: :func:`same_kind` (arguments of one kind),
:func:`checked_cross_cov` (a dependent pair's cross-covariance), :func:`chain_axis` (a chain's
axis; of a batch shape, :func:`chain_batch_axis`), :func:`batch_shape_of`; :func:`check_result`
checks relmap's own results for overflow.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import Any, ClassVar, TypeVar

import numpy as np

from relmap.errors import ArgumentTypeError, NumericalError, ParameterError, ShapeError
from relmap.lie.group import Group
from relmap.typing import ArrayLike, FloatArray, SeedLike
from relmap.uncertain import gaussian
from relmap.uncertain.gaussian import Ellipse

__all__ = ["UncertainPose"]

P = TypeVar("P", bound="UncertainPose")


class UncertainPose:
    """The shared base of :class:`relmap.AT` and :class:`relmap.AT3` (not used directly)."""

    __slots__ = ("_cov", "_mean")
    group: ClassVar[Group]  #: the pose group (generic code reads it)
    #: where the translation sits in a mean (the kind states it: ``[..., :2]`` of SE(2)'s
    #: ``(x, y, θ)``, ``[..., :3, 3]`` of SE(3)'s matrices)
    _translation: ClassVar[tuple[Any, ...]]
    #: the dimension n of the space the poses move in (SE(n): 2 for AT, 3 for AT3); the
    #: covariance's position block is its first n × n (:attr:`position_cov`)
    dim: ClassVar[int]
    _mean: FloatArray
    _cov: FloatArray
    __array_ufunc__ = None  # numpy defers to the pose: ``a @ ndarray`` is a TypeError, not a cast

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "group" in vars(cls):  # SE(n) has n (n + 1) / 2 degrees of freedom
            cls.dim = (math.isqrt(8 * cls.group.dof + 1) - 1) // 2
            # the group's shapes as plain class attributes (read by every _trusted)
            cls._point_shape = cls.group.point_shape
            cls._cov_shape = (cls.group.dof, cls.group.dof)

    _point_shape: ClassVar[tuple[int, ...]]
    _cov_shape: ClassVar[tuple[int, int]]

    # ------------------------------------------------------------------- storage
    def _set(self, mean: FloatArray, cov: FloatArray, batch: tuple[int, ...]) -> None:
        # read-only views: the arrays cannot be modified through the pose
        object.__setattr__(self, "_mean", _read_only(mean, (*batch, *self._point_shape)))
        object.__setattr__(self, "_cov", _read_only(cov, (*batch, *self._cov_shape)))

    @classmethod
    def _trusted(cls: type[P], mean: FloatArray, cov: FloatArray) -> P:
        """Build from arrays relmap computed itself (already valid, angles wrapped): no checks."""
        out = object.__new__(cls)
        batch = mean.shape[: mean.ndim - len(cls._point_shape)]
        if cov.shape[:-2] != batch:
            batch = np.broadcast_shapes(batch, cov.shape[:-2])
        out._set(mean, cov, batch)
        return out

    def __reduce__(self) -> tuple[object, ...]:
        """Pickle as the two arrays (values travel to Dask workers, ``relmap.sim.distributed``)."""
        return (type(self)._trusted, (np.array(self._mean), np.array(self._cov)))

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable; operations return new ATs")

    # --------------------------------------------------------------- constructors
    @classmethod
    def identity(cls: type[P], batch_shape: tuple[int, ...] = ()) -> P:
        """The exactly known identity transformation (of the given batch shape)."""
        shape = batch_shape_of(batch_shape)
        dof = cls.group.dof
        return cls._trusted(cls.group.identity(shape), np.zeros((*shape, dof, dof)))

    @classmethod
    def stack(cls: type[P], ats: Sequence[P], axis: int = 0) -> P:
        """Stack poses of equal batch shape along a new batch axis (like ``np.stack``)."""
        what = f"{cls.__name__}.stack"
        items = _sequence_of(ats, what)
        for i, x in enumerate(items):
            if not isinstance(x, cls):
                raise ArgumentTypeError(
                    f"{what}: item {i} is a {type(x).__name__}, not an {cls.__name__}"
                )
        ax = _stack_axis(items, axis, what)
        return cls._trusted(
            np.stack([a._mean for a in items], ax), np.stack([a._cov for a in items], ax)
        )

    @staticmethod
    def _diagonal_cov(sigmas: ArrayLike, dof: int) -> FloatArray:
        """``diag(σ²)`` ``(..., dof, dof)`` from standard deviations ``(..., dof)``, checked."""
        s = gaussian.real_array(sigmas, "sigmas")
        if s.ndim == 0 or s.shape[-1] != dof:
            raise ShapeError(f"sigmas must have shape (..., {dof}); got {s.shape}")
        gaussian.check_finite(s, "sigmas")
        if (s < 0).any():
            raise ParameterError(f"standard deviations must be non-negative; got {s.min()}")
        cov = np.zeros((*s.shape, dof))
        idx = np.arange(dof)
        cov[..., idx, idx] = s * s
        return cov

    # ------------------------------------------------------------------ accessors
    @property
    def mean(self) -> FloatArray:
        """The read-only mean, a point of :attr:`group`: ``(..., 3)`` ``(x, y, θ)`` for an AT,
        ``(..., 4, 4)`` homogeneous matrices for an AT3."""
        return self._mean

    @property
    def cov(self) -> FloatArray:
        """``(..., dof, dof)`` read-only covariance in the chart, translation first, in the
        parent frame."""
        return self._cov

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """Leading batch axes (``()`` for a single pose)."""
        return self._mean.shape[: self._mean.ndim - len(self._point_shape)]

    @property
    def ndim(self) -> int:
        """Number of batch axes."""
        return self._mean.ndim - len(self._point_shape)

    @property
    def sigmas(self) -> FloatArray:
        """``(..., dof)`` standard deviations of the chart's coordinates."""
        return np.sqrt(np.diagonal(self._cov, axis1=-2, axis2=-1))

    @property
    def position_cov(self) -> FloatArray:
        """``(..., n, n)`` the covariance of the position (n = :attr:`dim`), in the parent
        frame."""
        n = self.dim
        return self._cov[..., :n, :n]

    @property
    def vector(self) -> FloatArray:
        """The mean as JSON and text files write it, ``(..., k)``: the mean itself where it is
        a vector (SE(2)'s ``(x, y, θ)``); a kind whose mean is a matrix overrides it (AT3:
        ``[x, y, z, qx, qy, qz, qw]``)."""
        return self._mean

    def _position(self) -> FloatArray:
        """``(..., n)`` the child origin in the parent frame (n = :attr:`dim`)."""
        return self._mean[self._translation]

    def __getitem__(self: P, index: object) -> P:
        """Index the batch axes (never the trailing pose axes)."""
        name = type(self).__name__
        if self.ndim == 0:
            raise IndexError(f"a single {name} has no batch axes to index")
        idx = index if isinstance(index, tuple) else (index,)
        if any(i is Ellipsis for i in idx):
            raise IndexError(
                f"{name} indexing does not support Ellipsis; index the batch axes explicitly"
            )
        if sum(i is not None for i in idx) > self.ndim:
            raise IndexError(f"too many indices for an {name} with batch shape {self.batch_shape}")
        return type(self)._trusted(self._mean[idx], self._cov[idx])

    def __len__(self) -> int:
        """Length of the first batch axis (a single pose has none)."""
        if self.ndim == 0:
            raise TypeError(f"a single {type(self).__name__} has no length")
        return self.batch_shape[0]

    def __iter__(self: P) -> Iterator[P]:
        """Iterate over the first batch axis."""
        if self.ndim == 0:
            raise TypeError(f"a single {type(self).__name__} is not iterable")
        return (self[i] for i in range(self.batch_shape[0]))

    # ----------------------------------------------------------------- operations
    def sample(self, n: int, seed: SeedLike = None) -> FloatArray:
        """``n`` draws of the pose from ``N(mean, cov)`` in the chart, ``(n, ..., *point)``."""
        delta = gaussian._sample(np.zeros(self.group.dof), self._cov, n, seed)
        return self.group.plus(self._mean, delta)

    def ellipse(self, probability: float = 0.90) -> Ellipse:
        """Confidence ellipse of the horizontal position ``(x, y)``'s marginal, in the parent
        frame (Appendix A, N = 2)."""
        return gaussian._ellipse(self._position()[..., :2], self._cov[..., :2, :2], probability)

    # The operations each kind writes in its own module (relmap.uncertain.at, .at3), called by
    # relmap.uncertain.algebra's free functions after the shared checks and by the kind's own
    # ``a @ b`` and ``a.reverse()``; the base never calls them.
    def _compound(self: P, other: P, cross_cov: FloatArray | None) -> P:
        """``self ⊕ other`` (batches broadcast; ``cross_cov`` already checked, or None)."""
        raise NotImplementedError

    def _reverse(self, jacobians: bool) -> Any:
        """``selfᴿ``, and with ``jacobians`` the reversal's Jacobian too."""
        raise NotImplementedError

    @classmethod
    def _merge(cls: type[P], ats: Sequence[P], atol: float) -> P:
        """The merge of independent ``ats`` (two or more, of this kind)."""
        raise NotImplementedError

    def _chain(self: P, axis: int) -> P:
        """Every prefix compound along batch ``axis`` (checked by :func:`chain_axis`)."""
        raise NotImplementedError


# ------------------------------------------------------------------------ the checks
def same_kind(items: Sequence[object], expected: str = "AT") -> type[UncertainPose]:
    """The kind (class) of ``items``, all of the first one's kind; else an
    :class:`ArgumentTypeError` naming the first that is not (``expected`` names the kind when
    the first item is no pose at all)."""
    first = items[0]
    kind = type(first) if isinstance(first, UncertainPose) else None
    for i, x in enumerate(items):
        if kind is None or not isinstance(x, kind):
            name = expected if kind is None else kind.__name__
            raise ArgumentTypeError(f"argument {i} is a {type(x).__name__}, not an {name}")
    return kind  # type: ignore[return-value]


def check_result(what: str, *arrays: FloatArray) -> None:
    """Raise :class:`NumericalError` if relmap's own arithmetic overflowed (inf or NaN): only
    possible for inputs near the floating-point range (e.g. translations of 1e300 m, whose
    squares in the covariance overflow). The one check on the paths of relmap's results."""
    for arr in arrays:
        # a sum is the cheapest test (NaN and inf propagate through it); only when it is not
        # finite are the entries tested, since a sum of huge finite entries can overflow too
        total = sum(arr.ravel().tolist()) if arr.size <= 64 else np.add.reduce(arr, axis=None)
        if not math.isfinite(total) and not np.isfinite(arr).all():
            raise overflow_error(what)


def overflow_error(what: str) -> NumericalError:
    """The error of a result of relmap's own arithmetic that overflowed (:func:`check_result`;
    relmap's compiled core reports it for the results it makes)."""
    return NumericalError(
        f"{what} overflowed the floating-point range (inputs too large): the result would hold "
        "inf or NaN"
    )


def checked_cross_cov(Ca: FloatArray, Cb: FloatArray, value: ArrayLike, n: int) -> FloatArray:
    """``value``, the cross-covariance ``E[δa δbᵀ]`` of a dependent pair, checked: shape
    ``(..., n, n)``, finite, and the joint covariance ``[[C_a, C_ab], [C_abᵀ, C_b]]`` positive
    semi-definite (else the compound's variances could come out negative)."""
    X = gaussian.real_array(value, "cross_cov")
    if X.shape[-2:] != (n, n):
        raise ShapeError(f"cross_cov must have shape (..., {n}, {n}); got {X.shape}")
    gaussian.check_finite(X, "cross_cov")
    try:
        batch = np.broadcast_shapes(Ca.shape[:-2], Cb.shape[:-2], X.shape[:-2])
    except ValueError:
        raise broadcast_error("cross_cov", Ca.shape[:-2], Cb.shape[:-2], X.shape[:-2]) from None
    joint = np.empty((*batch, 2 * n, 2 * n))
    joint[..., :n, :n], joint[..., n:, n:] = Ca, Cb
    joint[..., :n, n:] = X
    joint[..., n:, :n] = np.swapaxes(X, -1, -2)
    gaussian.validate_covariance(
        joint, name="the joint covariance [[C_a, cross_cov], [cross_covᵀ, C_b]]"
    )
    return X


def chain_axis(steps: UncertainPose, axis: object, what: str) -> int:
    """The chain's batch ``axis`` of ``steps`` as a non-negative int, checked by
    :func:`chain_batch_axis`."""
    return chain_batch_axis(steps.batch_shape, axis, what, f"an {type(steps).__name__}")


def chain_batch_axis(batch: tuple[int, ...], axis: object, what: str, name: str) -> int:
    """The chain's ``axis`` of batch shape ``batch`` as a non-negative int, checked: there is a
    batch axis, ``axis`` is an integer in range, and the chain has at least one step.
    ``what`` names the operation, ``name`` its input (for the errors)."""
    if not batch:
        raise ShapeError(f"{what} needs {name} with at least one batch axis (the chain)")
    if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)):
        raise ParameterError(f"axis must be an integer; got {axis!r}")
    if not -len(batch) <= axis < len(batch):
        raise ShapeError(f"axis {axis} is out of range for batch shape {batch}")
    if batch[axis] == 0:
        raise ShapeError(
            f"{what} needs at least one step along axis {axis}; batch shape {batch} has none"
        )
    return int(axis) % len(batch)


def batch_shape_of(shape: object) -> tuple[int, ...]:
    """``shape`` as a batch shape (a tuple of non-negative integers), or a ShapeError."""
    items = (shape,) if isinstance(shape, (int, np.integer)) else shape
    if (
        isinstance(items, (str, bytes))
        or not isinstance(items, (tuple, list))
        or not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) for n in items)
        or any(n < 0 for n in items)
    ):
        raise ShapeError(f"batch_shape must be a tuple of non-negative integers; got {shape!r}")
    out = tuple(int(n) for n in items)
    if math.prod(out) * 52 * 8 > gaussian._MAX_SAMPLE_BYTES:  # a 4×4 mean and a 6×6 cov each
        raise ShapeError(f"batch_shape {out} is too large to hold in memory")
    return out


def common_batch(what: str, ats: Sequence[UncertainPose]) -> tuple[int, ...]:
    """The broadcast batch shape of ``ats`` (or :func:`broadcast_error`'s ShapeError)."""
    try:
        return np.broadcast_shapes(*(x.batch_shape for x in ats))
    except ValueError:
        raise broadcast_error(what, *(x.batch_shape for x in ats)) from None


def broadcast_error(what: str, *shapes: tuple[int, ...]) -> ShapeError:
    """The :class:`ShapeError` of batch shapes that do not broadcast."""
    shown = " and ".join(str(s) for s in shapes)
    return ShapeError(f"{what}: batch shapes {shown} do not broadcast")


def _sequence_of(ats: object, what: str) -> list:  # type: ignore[type-arg]
    """``ats`` as a non-empty list (for :meth:`UncertainPose.stack`)."""
    try:
        if isinstance(ats, (str, bytes, dict)):
            raise TypeError
        out = list(ats)  # type: ignore[call-overload]
    except TypeError:
        raise ArgumentTypeError(
            f"{what} needs a sequence of ATs; got a {type(ats).__name__}"
        ) from None
    if not out:
        raise ShapeError(f"{what} needs at least one AT")
    return out


def _stack_axis(ats: Sequence[UncertainPose], axis: object, what: str) -> int:
    """The new axis of a stack of poses of equal batch shape (checked), as a non-negative int."""
    shapes = {a.batch_shape for a in ats}
    if len(shapes) > 1:
        raise ShapeError(f"{what} needs ATs of one batch shape; got {sorted(shapes)}")
    ndim = ats[0].ndim
    if isinstance(axis, bool) or not isinstance(axis, (int, np.integer)):
        raise ParameterError(f"{what}: axis must be an integer; got {axis!r}")
    if not -ndim - 1 <= axis <= ndim:
        raise ShapeError(f"{what}: axis {axis} is out of range for {ndim + 1} batch axes")
    return int(axis) if axis >= 0 else int(axis) + ndim + 1


def _read_only(arr: FloatArray, shape: tuple[int, ...]) -> FloatArray:
    """A read-only view of ``arr`` broadcast to ``shape`` (a plain view when it has that shape:
    np.broadcast_to costs microseconds, which matter for single values; ``arr`` itself when it
    is read-only already, e.g. a result of the compiled core)."""
    if arr.shape != shape:
        return np.broadcast_to(arr, shape)
    if not arr.flags.writeable:
        return arr
    view = arr.view()
    view.setflags(write=False)  # (not view.flags.writeable = False: that builds a flags object)
    return view
