"""Blocks of independent work, here or on a Dask cluster (the optional ``relmap[distributed]``).

:func:`map_blocks` evaluates ``fn(job, j)`` for every block ``j`` and hands each result to the
caller as its chunk completes. Blocks are grouped into *chunks* of consecutive blocks, sized
to a target time of work per task from the time the first chunks took (one block each at
first); a chunk is one task. With ``client=None`` the chunks run one after another in this
process; with a ``distributed.Client`` (or a scheduler address) they run on the cluster's
workers, the ``job`` sent to every worker once (scattered), at most two chunks per worker
thread in flight (so nothing grows with the number of blocks). It is the same loop either way:
only where a chunk runs differs. A worker lost mid-run costs nothing but time: the scheduler
runs its chunks again elsewhere, and as every block's result depends on its index only, the
results are the same.

``import relmap`` does not import dask: this module imports it when a cluster is asked for.
"""

from __future__ import annotations

import contextlib
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import CancelledError
from typing import Any, NamedTuple

from relmap.errors import ChunkError, ClusterError, ParameterError

__all__ = ["CHUNK_SECONDS", "CONNECT_SECONDS", "Work", "check_workers", "client_for", "connect",
           "local_client", "map_blocks", "workers_of"]  # fmt: skip

#: Target seconds of work per chunk (task).
CHUNK_SECONDS = 0.5
#: How long to try to reach a scheduler before giving up.
CONNECT_SECONDS = 5.0
#: How long to wait for a first worker on a cluster that has none yet.
WORKER_SECONDS = 60.0
#: How often a chunk the scheduler dropped (with a dead worker) is submitted again.
RETRIES = 3
#: Packages every worker needs (a worker missing one is named in the error).
NEEDED = ("relmap", "numpy", "scipy")

Client = Any  # distributed.Client: typed loosely, dask is optional


class Work(NamedTuple):
    """How a :func:`map_blocks` went: chunks (tasks), the seconds they computed in all (on
    the workers: scheduling and transfer excluded), and the worker threads (1 here)."""

    chunks: int
    busy_seconds: float
    slots: int


def _need_distributed() -> Any:
    try:
        import distributed
    except ImportError:
        raise ClusterError(
            "running on a Dask cluster needs the 'distributed' package: "
            "pip install 'relmap[distributed]'"
        ) from None
    return distributed


def connect(
    address: str, *, timeout: float = CONNECT_SECONDS, worker_timeout: float = WORKER_SECONDS
) -> Client:
    """A client of the Dask scheduler at ``address`` (e.g. ``tcp://10.0.0.5:8786``), with at
    least one worker whose packages are checked (:func:`check_workers`).

    An unreachable scheduler raises :class:`relmap.errors.ClusterError` after ``timeout``
    seconds; a scheduler with no worker after ``worker_timeout`` more.
    """
    distributed = _need_distributed()
    if not isinstance(address, str) or not address.strip():
        raise ParameterError(
            f"a scheduler address is a string such as tcp://host:8786; got {address!r}"
        )
    try:
        client = distributed.Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise ClusterError(
            f"cannot reach the Dask scheduler at {address!r} within {timeout:g} s "
            f"({type(exc).__name__}: {exc})"
        ) from None
    except (ValueError, TypeError) as exc:
        raise ParameterError(f"not a scheduler address: {address!r} ({exc})") from None
    try:
        check_workers(client, timeout=worker_timeout)
    except BaseException:
        client.close()
        raise
    return client


@contextlib.contextmanager
def local_client(workers: int) -> Iterator[Client]:
    """A ``LocalCluster`` of ``workers`` processes (one thread each) on this machine and a
    client of it, closed on exit."""
    if isinstance(workers, bool) or int(workers) != workers or workers < 1:
        raise ParameterError(f"workers must be a positive integer; got {workers!r}")
    distributed = _need_distributed()
    import logging

    cluster = distributed.LocalCluster(
        n_workers=int(workers),
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=logging.ERROR,
    )
    try:
        with distributed.Client(cluster, set_as_default=False) as client:
            yield client
    finally:
        cluster.close()


@contextlib.contextmanager
def client_for(workers: int | None = None, scheduler: str | None = None) -> Iterator[Client | None]:
    """The client a command's ``--workers N`` or ``--scheduler ADDRESS`` asks for: a local
    cluster of N processes (:func:`local_client`), the cluster at ADDRESS (:func:`connect`),
    or None (this process) when neither is given; closed on exit. Both at once is a
    :class:`relmap.errors.ParameterError`."""
    if workers is not None and scheduler is not None:
        raise ParameterError("give the number of local workers or a scheduler address, not both")
    if scheduler is not None:
        client = connect(scheduler)
        try:
            yield client
        finally:
            client.close()
    elif workers is not None:
        with local_client(workers) as client:
            yield client
    else:
        yield None


def _probe_factory() -> Callable[[], dict[str, str | None]]:
    def probe() -> dict[str, str | None]:  # runs on a worker: sent by value, needs no relmap
        import importlib

        found: dict[str, str | None] = {}
        for name in ("relmap", "numpy", "scipy"):
            try:
                found[name] = str(getattr(importlib.import_module(name), "__version__", "?"))
            except ImportError:
                found[name] = None
        return found

    return probe


def check_workers(
    client: Client, *, timeout: float = WORKER_SECONDS
) -> dict[str, dict[str, str | None]]:
    """Each worker's versions of :data:`NEEDED`; raise :class:`relmap.errors.ClusterError` if
    there is no worker within ``timeout`` s, if a worker lacks one of them (naming it), or runs
    another relmap version than this process."""
    from relmap._version import __version__

    try:
        client.wait_for_workers(1, timeout=timeout)
    except TimeoutError:
        raise ClusterError(
            f"no Dask worker joined the scheduler at {client.scheduler.address} within "
            f"{timeout:g} s (start workers with: dask worker {client.scheduler.address})"
        ) from None
    versions: dict[str, dict[str, str | None]] = client.run(_probe_factory())
    for worker, found in sorted(versions.items()):
        missing = [name for name in NEEDED if found.get(name) is None]
        if missing:
            raise ClusterError(
                f"Dask worker {worker} cannot import {', '.join(missing)}: install it on every "
                f"worker (pip install 'relmap[distributed]', the same version as here, "
                f"{__version__})"
            )
        if found["relmap"] != __version__:
            raise ClusterError(
                f"Dask worker {worker} runs relmap {found['relmap']}, this process "
                f"{__version__}: install the same version on every worker"
            )
    return versions


def workers_of(client: Client) -> int:
    """Worker threads of a cluster (at least 1)."""
    return max(1, sum(client.nthreads().values()))


def _chunk(
    fn: Callable[[Any, int], Any], job: Any, first: int, stop: int
) -> tuple[list[Any], float]:
    """One task: blocks ``first … stop-1`` in order, and the seconds they took."""
    t0 = time.perf_counter()
    out = [fn(job, j) for j in range(first, stop)]
    return out, time.perf_counter() - t0


class _Here:
    """Chunks run in this process, one at a time, when their result is asked for."""

    depth = 1
    slots = 1

    def __init__(self, fn: Callable[[Any, int], Any], job: Any) -> None:
        self.fn, self.job = fn, job
        self.queue: deque[tuple[int, int]] = deque()

    def submit(self, first: int, stop: int) -> None:
        self.queue.append((first, stop))

    def next_done(self) -> tuple[int, int, list[Any], float]:
        first, stop = self.queue.popleft()
        return (first, stop, *_chunk(self.fn, self.job, first, stop))

    def cancel(self) -> None:
        self.queue.clear()


class _OnCluster:
    """Chunks run as Dask tasks; ``job`` scattered to every worker once."""

    def __init__(self, client: Client, fn: Callable[[Any, int], Any], job: Any) -> None:
        distributed = _need_distributed()
        self.client, self.fn = client, fn
        self.slots = workers_of(client)
        self.depth = 2 * self.slots
        self.job = client.scatter(job, broadcast=True, hash=False)
        self.done = distributed.as_completed(loop=client.loop)
        self.running: dict[str, tuple[Any, int, int, int]] = {}
        self.token = uuid.uuid4().hex[:12]
        self._job = job

    def submit(self, first: int, stop: int, attempt: int = 0) -> None:
        name = getattr(self.fn, "__name__", "block")
        key = f"relmap-{name}-{self.token}-{first}-{stop}-{attempt}"
        future = self.client.submit(_chunk, self.fn, self.job, first, stop, key=key, pure=False)
        self.running[future.key] = (future, first, stop, attempt)
        self.done.add(future)

    def next_done(self) -> tuple[int, int, list[Any], float]:
        while True:
            future = next(self.done)
            _, first, stop, attempt = self.running.pop(future.key)
            try:
                out, seconds = self._result(future, first, stop)
            except CancelledError:
                # Not cancelled here: the scheduler dropped the chunk with a dead worker (its
                # input, the scattered job, may have gone with it). Scatter it again and rerun.
                if attempt >= RETRIES:
                    raise ClusterError(
                        f"Dask dropped blocks {first}-{stop - 1} {attempt + 1} times (workers "
                        "dying?)"
                    ) from None
                self.job = self.client.scatter(self._job, broadcast=True, hash=False)
                self.submit(first, stop, attempt + 1)
                continue
            return first, stop, out, seconds

    def _result(self, future: Any, first: int, stop: int) -> tuple[list[Any], float]:
        try:
            return future.result()
        except (ChunkError, CancelledError):
            raise
        except ModuleNotFoundError as exc:
            raise ClusterError(
                f"a Dask worker cannot import {exc.name or exc}: install relmap "
                "(pip install 'relmap[distributed]') on every worker"
            ) from None
        except Exception as exc:
            if type(exc).__name__ == "KilledWorker":
                raise ClusterError(
                    f"Dask workers died running blocks {first}-{stop - 1} again and again: {exc}"
                ) from None
            raise
        finally:
            future.release()

    def cancel(self) -> None:
        futures = [f for f, _, _, _ in self.running.values()]
        if futures:
            self.client.cancel(futures, force=True)
        self.running.clear()
        self.client.cancel([self.job], force=True)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.client.cancel([self.job], force=True)


@contextlib.contextmanager
def _client_of(client: Client | str | None) -> Iterator[Client | None]:
    if client is None or not isinstance(client, str):
        yield client
        return
    c = connect(client)
    try:
        yield c
    finally:
        c.close()


def map_blocks(
    fn: Callable[[Any, int], Any],
    job: Any,
    blocks: int,
    consume: Callable[[int, Any], None],
    *,
    client: Client | str | None = None,
    chunk_seconds: float | None = None,
    on_chunk: Callable[[], None] | None = None,
) -> Work:
    """Call ``consume(j, fn(job, j))`` for every block ``0 ≤ j < blocks`` (in any order, as
    chunks complete), then ``on_chunk()`` after each chunk (module docstring); return how the
    work went (:class:`Work`).

    ``fn`` must be importable on the workers (a module-level function of relmap). Ctrl-C (or
    any error) cancels every chunk still pending before it propagates.
    """
    target = CHUNK_SECONDS if chunk_seconds is None else float(chunk_seconds)
    if not target > 0:
        raise ParameterError(f"chunk_seconds must be positive; got {chunk_seconds}")
    with _client_of(client) as c:
        if c is not None and not isinstance(c, _need_distributed().Client):
            raise ParameterError(
                "client must be a distributed.Client or a scheduler address; "
                f"got {type(c).__name__}"
            )
        if c is not None and not isinstance(client, str):
            check_workers(c)
        ex: _Here | _OnCluster = _Here(fn, job) if c is None else _OnCluster(c, fn, job)
        submitted, inflight, timed_blocks, timed_seconds, chunks = 0, 0, 0, 0.0, 0
        try:
            while submitted < blocks or inflight:
                while submitted < blocks and inflight < ex.depth:
                    if timed_blocks == 0:
                        size = 1
                    else:
                        per_block = max(timed_seconds / timed_blocks, 1e-9)
                        fair = -(-(blocks - submitted) // (2 * ex.slots))  # leave some for all
                        size = max(1, min(fair, int(target / per_block)))
                    stop = min(blocks, submitted + size)
                    ex.submit(submitted, stop)
                    submitted, inflight = stop, inflight + 1
                first, stop, out, seconds = ex.next_done()
                inflight, chunks = inflight - 1, chunks + 1
                timed_blocks, timed_seconds = timed_blocks + stop - first, timed_seconds + seconds
                for j, result in zip(range(first, stop), out, strict=True):
                    consume(j, result)
                if on_chunk is not None:
                    on_chunk()
        except BaseException:
            ex.cancel()
            raise
        finally:
            if isinstance(ex, _OnCluster):
                ex.close()
        return Work(chunks, timed_seconds, ex.slots)
