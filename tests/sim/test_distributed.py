"""Monte Carlo and studies on a Dask LocalCluster of 2 worker processes started here.

The same seed gives the same bits as one process; a worker killed mid-run loses no sample; a
failing block names its seed; Ctrl-C cancels; bad clusters give clear errors.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from relmap.app import validate  # noqa: E402
from relmap.app.cli import main  # noqa: E402
from relmap.errors import ChunkError, ClusterError, ParameterError  # noqa: E402
from relmap.io import save_map  # noqa: E402
from relmap.sim import montecarlo, study  # noqa: E402
from relmap.sim.distributed import connect, local_client  # noqa: E402
from tests.app.test_validate import bridge_map  # noqa: E402


@pytest.fixture(scope="module")
def client():
    with local_client(2) as c:
        yield c


def _same(a: validate.Validation, b: validate.Validation) -> None:
    for field in a.agreement._fields:
        assert np.array_equal(getattr(a.agreement, field), getattr(b.agreement, field)), field
    for field in ("mean", "cov", "samples"):
        assert np.array_equal(getattr(a.samples, field), getattr(b.samples, field)), field
    assert a.samples.n == b.samples.n


@pytest.mark.parametrize(("method", "n"), [("reduce", 10_000), ("optimal", 40)])
def test_two_workers_give_the_bits_of_one_process(client, method, n):
    g = bridge_map(np.radians(2.0))
    here = validate.validate_query(g, "w", "u", method=method, n=n, seed=11)
    there = validate.validate_query(g, "w", "u", method=method, n=n, seed=11, client=client)
    _same(here, there)
    assert here.blocks == there.blocks > 1


@pytest.mark.slow
def test_a_killed_worker_loses_no_sample(client):
    """One worker process is killed after the first chunk: its chunks run again elsewhere
    (the nanny restarts it), and every number is as in one process."""
    g = bridge_map(np.radians(2.0))
    p = validate.plan(g, "w", "u", method="optimal")
    here = validate.run(p, n=96, seed=5)
    pids = client.run(os.getpid)
    killed = []

    def kill_one(k: int, n: int) -> None:
        busy = {w: keys for w, keys in client.processing().items() if keys}
        if not killed and busy:
            victim = sorted(busy)[0]  # a worker holding chunks right now
            os.kill(pids[victim], signal.SIGKILL)
            killed.append(victim)

    there = validate.run(p, n=96, seed=5, client=client, progress=kill_one, chunk_seconds=0.05)
    assert killed
    _same(here, there)
    client.wait_for_workers(2, timeout=60)


def _fails_in_block_3(problem, rng, m):
    if rng.bit_generator.seed_seq.spawn_key[-1] == 3:
        raise ValueError("no solution for this draw")
    return rng.standard_normal((m, 3)) * 0.1


def test_a_failing_block_names_its_seed(client):
    import relmap as rm

    est = rm.AT([0.0, 0.0, 0.0], np.eye(3) * 0.01)
    for where in (None, client):
        with pytest.raises(
            ChunkError, match=r"block 3 .*entropy=99, spawn_key=\(3,\).*no solution"
        ):
            montecarlo.run(_fails_in_block_3, None, est, n=100, seed=99, block=10, client=where)
    try:
        montecarlo.run(_fails_in_block_3, None, est, n=100, seed=99, block=10, client=client)
    except ChunkError as exc:
        assert exc.block == 3 and exc.seed == (99, (3,))
        rng = np.random.default_rng(np.random.SeedSequence(99, spawn_key=(3,)))
        with pytest.raises(ValueError):
            _fails_in_block_3(None, rng, 10)  # the seed reproduces the failure here


def test_ctrl_c_cancels_the_pending_chunks(client):
    p = validate.plan(bridge_map(np.radians(2.0)), "w", "u", method="optimal")

    def interrupt(k: int, n: int) -> None:
        raise KeyboardInterrupt

    def tasks() -> set[str]:
        return set(client.run_on_scheduler(lambda dask_scheduler: list(dask_scheduler.tasks)))

    before = tasks()
    with pytest.raises(KeyboardInterrupt):
        validate.run(p, n=400, seed=1, client=client, progress=interrupt)
    left = None
    for _ in range(200):  # the scheduler forgets cancelled tasks shortly after
        left = tasks() - before
        if not left:
            break
        time.sleep(0.1)
    assert not left


def _sensing(sigma, map_):  # a forecast_sensing noise sweep, one point
    f = map_.forecast_sensing(("u", "w"), np.diag([sigma**2, sigma**2, 1e-4]), ("t", "v"))
    return {"position_shrink": f.position_shrink}


def test_a_study_on_the_cluster_is_the_study_here(client):
    g = bridge_map(np.radians(1.0))
    points = study.grid(sigma=[0.01, 0.1, 1.0])
    here = study.run(_sensing, points, shared={"map_": g})
    there = study.run(_sensing, points, shared={"map_": g}, client=client)
    assert here.rows == there.rows and here.columns == ("sigma", "position_shrink")
    shrink = here.column("position_shrink")
    assert shrink[0] < shrink[1] < shrink[2] <= 1.0  # a worse sensor helps less


def test_cli_on_a_scheduler_prints_the_numbers_of_one_process(client, tmp_path, capsys):
    path = tmp_path / "bridge.yaml"
    save_map(path, bridge_map(np.radians(2.0)))
    args = ["validate", str(path), "w", "u", "-n", "64", "--seed", "3", "--json"]
    assert main(args) == 0
    here = json.loads(capsys.readouterr().out)
    assert main([*args, "--scheduler", client.scheduler.address]) == 0
    captured = capsys.readouterr()
    there = json.loads(captured.out)
    here.pop("seconds"), there.pop("seconds")
    assert here == there
    assert "auto chose optimal" in captured.err and "Dask cluster" in captured.err


def test_workers_without_relmap_are_named(client):
    def hide_relmap():  # as if relmap were not installed on the worker
        saved = {k: v for k, v in sys.modules.items() if k.split(".")[0] == "relmap"}
        sys.modules.update(dict.fromkeys(saved))
        sys.modules["_relmap_hidden"] = saved  # type: ignore[assignment]

    def restore():
        sys.modules.update(sys.modules.pop("_relmap_hidden"))  # type: ignore[arg-type]

    client.run(hide_relmap)
    try:
        with pytest.raises(ClusterError, match="cannot import relmap"):
            validate.validate_query(bridge_map(0.01), "w", "u", n=8, client=client)
    finally:
        client.run(restore)


def test_an_unreachable_scheduler_is_a_clear_error(capsys):
    t0 = time.perf_counter()
    with pytest.raises(ClusterError, match="cannot reach the Dask scheduler"):
        connect("tcp://127.0.0.1:9", timeout=1.0)
    assert time.perf_counter() - t0 < 60  # a hang guard, not a speed test
    with pytest.raises(ParameterError):
        connect("")
    assert main(["validate", "nowhere.yaml", "w", "u", "--workers", "0"]) == 2
    assert "--workers must be a positive integer" in capsys.readouterr().err
    with pytest.raises(ParameterError):
        with local_client(-1):
            pass


@pytest.mark.slow
def test_cli_workers_starts_its_own_cluster(tmp_path, capsys):
    path = tmp_path / "bridge.yaml"
    save_map(path, bridge_map(np.radians(2.0)))
    args = ["validate", str(path), "w", "u", "-n", "5000", "--method", "reduce", "--json"]
    assert main(args) == 0
    here = json.loads(capsys.readouterr().out)
    assert main([*args, "--workers", "2"]) == 0
    there = json.loads(capsys.readouterr().out)
    here.pop("seconds"), there.pop("seconds")
    assert here == there


def test_client_for_a_commands_options():
    """--workers N / --scheduler ADDRESS: neither is this process (None), both is refused, a
    bad count is refused before any cluster starts."""
    from relmap.sim.distributed import client_for

    with client_for() as client:
        assert client is None
    with pytest.raises(ParameterError, match="not both"), client_for(2, "tcp://127.0.0.1:1"):
        pass
    with pytest.raises(ParameterError, match="positive"), client_for(0):
        pass
