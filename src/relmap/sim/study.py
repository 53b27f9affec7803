"""Batch studies: one function over a grid of parameters, here or on a Dask cluster.

>>> from relmap.sim import study
>>> def area(side, scale):
...     return {"area": (side * scale) ** 2}
>>> t = study.run(area, study.grid(side=[1.0, 2.0], scale=[1, 10]))
>>> t.column("area")
[1.0, 100.0, 4.0, 400.0]

:func:`run` calls ``fn(**point, **shared)`` for every point of the grid and returns a tidy
:class:`Table`: one row per point, the point's parameters then the function's results, in
grid order whatever order the points completed in. ``shared`` (a map, a dataset) is sent to
each worker once. ``client`` is None (this process), a ``distributed.Client`` or a scheduler
address; the points go out in chunks sized to the time they take
(:func:`relmap.sim.distributed.map_blocks`). A function that draws random numbers should take its
seed from the grid (a ``seed`` axis), so every row can be reproduced on its own.
"""

from __future__ import annotations

import csv
import io
import itertools
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any, NamedTuple

from relmap.errors import ChunkError, ParameterError
from relmap.typing import Option

__all__ = ["OnError", "Table", "grid", "run"]


class OnError(Option):
    """What :func:`run` does when a point raises: ``"raise"`` (stop, naming the point) or
    ``"record"`` (the error in an ``error`` column, and go on)."""

    RAISE = "raise"
    RECORD = "record"


Row = dict[str, Any]


def grid(**axes: Iterable[Any]) -> list[Row]:
    """Every combination of the named values, the first axis varying slowest:
    ``grid(robot=[1, 2], associate=["signatures", "mahalanobis"])`` has four points."""
    names = list(axes)
    values = [list(v) for v in axes.values()]
    for name, v in zip(names, values, strict=True):
        if not v:
            raise ParameterError(f"grid axis {name!r} has no values")
    return [dict(zip(names, combo, strict=True)) for combo in itertools.product(*values)]


class Table:
    """Rows of named values (a list of dicts, all with the same columns in the same order)."""

    def __init__(self, rows: Iterable[Mapping[str, Any]]) -> None:
        self.rows: tuple[Row, ...] = tuple(dict(r) for r in rows)
        cols: dict[str, None] = {}
        for r in self.rows:
            cols.update(dict.fromkeys(r))
        self.columns: tuple[str, ...] = tuple(cols)

    def __len__(self) -> int:
        return len(self.rows)

    def __iter__(self) -> Iterator[Row]:
        return iter(self.rows)

    def __getitem__(self, k: int) -> Row:
        return self.rows[k]

    def column(self, name: str) -> list[Any]:
        """The values of one column, in row order (None where a row lacks it)."""
        if name not in self.columns:
            raise ParameterError(f"no column {name!r}; the table has {', '.join(self.columns)}")
        return [r.get(name) for r in self.rows]

    def where(self, **match: Any) -> Table:
        """The rows whose columns equal the given values."""
        return Table(r for r in self.rows if all(r.get(k) == v for k, v in match.items()))

    def to_csv(self, path: str | None = None) -> str:
        """The table as CSV text; written atomically to ``path`` if given."""
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=self.columns, lineterminator="\n")
        w.writeheader()
        w.writerows(self.rows)
        text = buf.getvalue()
        if path is not None:
            from relmap.io.atomic import write_text_atomic

            write_text_atomic(path, text)
        return text

    def __str__(self) -> str:
        def fmt(v: Any) -> str:
            return f"{v:.4g}" if isinstance(v, float) else str(v)

        cells = [list(self.columns)] + [[fmt(r.get(c, "")) for c in self.columns] for r in self]
        widths = [max(len(row[i]) for row in cells) for i in range(len(self.columns))]
        return "\n".join(
            "  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)) for row in cells
        )

    def __repr__(self) -> str:
        return f"Table({len(self)} rows: {', '.join(self.columns)})"


class _Study(NamedTuple):
    fn: Callable[..., Any]
    points: tuple[Row, ...]
    shared: Mapping[str, Any]
    record_errors: bool


def _as_row(result: Any) -> Row:
    if isinstance(result, Mapping):
        return dict(result)
    if hasattr(result, "_asdict"):
        return dict(result._asdict())
    return {"value": result}


def _point(job: _Study, j: int) -> Row:
    """Point ``j`` of the study: its parameters, then what the function returned."""
    point = job.points[j]
    try:
        out = _as_row(job.fn(**point, **job.shared))
    except Exception as exc:
        if not job.record_errors:
            raise ChunkError(
                f"study point {j} {point!r} failed: {type(exc).__name__}: {exc}", block=j
            ) from exc
        out = {"error": f"{type(exc).__name__}: {exc}"}
    clash = set(out) & set(point)
    if clash:
        raise ChunkError(
            f"study point {j}: the results reuse the parameter names {sorted(clash)}", block=j
        )
    return {**point, **out}


def run(
    fn: Callable[..., Any],
    points: Sequence[Mapping[str, Any]] | Mapping[str, Iterable[Any]],
    *,
    client: Any = None,
    shared: Mapping[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
    on_error: OnError | str = OnError.RAISE,
) -> Table:
    """``fn(**point, **shared)`` for every point, as a :class:`Table` (module docstring).

    ``points``: a list of parameter dicts, or a dict of axes (→ :func:`grid`). ``fn`` returns
    a dict (or a NamedTuple, or one value: column ``value``); it must be picklable for a
    cluster (a module-level function). ``on_error`` (an :class:`OnError`): ``"raise"`` stops at
    the first point that raises (:class:`relmap.errors.ChunkError` naming the point),
    ``"record"`` puts the error in an ``error`` column and goes on. ``progress(k, n)`` is called
    as chunks complete.
    """
    from relmap.sim import distributed

    on_error = OnError.parse(on_error, "on_error")
    pts = tuple(dict(p) for p in (grid(**points) if isinstance(points, Mapping) else points))
    if not pts:
        raise ParameterError("the study has no points")
    job = _Study(fn, pts, dict(shared or {}), on_error is OnError.RECORD)
    rows: list[Row | None] = [None] * len(pts)
    done = [0]

    def consume(j: int, row: Row) -> None:
        rows[j] = row
        done[0] += 1

    def chunk_done() -> None:
        if progress is not None:
            progress(done[0], len(pts))

    distributed.map_blocks(_point, job, len(pts), consume, client=client, on_chunk=chunk_done)
    return Table(r for r in rows if r is not None)
