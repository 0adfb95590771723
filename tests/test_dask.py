"""Batches and replicates on Dask, on one LocalCluster of 2 worker processes: the
results equal the in-process batch's, a worker killed mid-run loses no project, `--resume`
skips finished projects; without Dask, `--scheduler` is refused before any work."""

import json
import os
import shutil
import signal
import sys
import threading
import time

import equinox as eqx
import jax
import numpy as np
import pytest

import jaxba
from jaxba._adjust._montecarlo import monte_carlo
from jaxba._adjust._padding import batch_shape, pad_problems
from jaxba._cli._batch_run import run_batch
from jaxba._cli._main import main
from jaxba._dask import check_scheduler, local_workers

N_PROJECTS = 20
SIZES = ((6, 20), (7, 24), (8, 28), (6, 26))  # (images, targets), cycled over the projects
EQUAL_RTOL = 1e-12  # Dask results equal the in-process batch's to 1e-12
CHUNK = 4  # projects per vmapped solve, here and on Dask: 5 tasks, several per worker


@pytest.fixture(scope="module")
def cluster():
    """(cluster, client): 2 single-threaded worker processes. They share this process's
    compilation cache (its folder is in the environment they inherit), as `jaxba batch
    --scheduler local` does: each test solves in this process first, so the workers load
    what it compiled, and never write an entry this process is reading. The dashboard (where
    bokeh is installed) on a free port: None means distributed's default, 8787, which a
    cluster of another test process may hold."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
    ) as cluster, distributed.Client(cluster) as client:
        yield cluster, client


@pytest.fixture(scope="module")
def projects(tmp_path_factory):
    root = tmp_path_factory.mktemp("dask_projects")
    paths = []
    for k in range(N_PROJECTS):
        n_images, n_targets = SIZES[k % len(SIZES)]
        truth = jaxba.write_synthetic_project(root / f"p{k:02d}", name=f"p{k:02d}", seed=70 + k,
                                              n_images=n_images, n_targets=n_targets)
        paths.append(truth.project_file)
    return paths


@pytest.fixture(scope="module")
def local(projects, tmp_path_factory):
    """The in-process batch, in the same chunks: (output folder, summary rows)."""
    out = tmp_path_factory.mktemp("local") / "out"
    return out, run_batch(projects, out, chunk_size=CHUNK)


@pytest.fixture(scope="module")
def on_dask(cluster, projects, tmp_path_factory):
    _, client = cluster
    out = tmp_path_factory.mktemp("dask") / "out"
    lines = []
    return out, run_batch(projects, out, scheduler=client, chunk_size=CHUNK,
                          progress=lines.append), lines


def _close(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return abs(a - b) <= EQUAL_RTOL * max(abs(a), abs(b), 1e-300)
    return a == b


def _assert_rows_equal(rows, expected, *, modes=None):
    assert len(rows) == len(expected)
    for k, (row, want) in enumerate(zip(rows, expected)):
        assert row.keys() == want.keys()
        assert row["mode"] == (modes[k] if modes else want["mode"])
        differ = [key for key in want if key != "mode" and not _close(row[key], want[key])]
        assert not differ, (row["name"], [(key, row[key], want[key]) for key in differ])


def _numbers(tree, key=None):
    """Every number of a results.json tree, in order, but its timings, as (value, scale):
    the entries of a covariance matrix scaled by σi σj, of a correlation matrix and of an
    ellipsoid's unit directions by 1 (their accuracy is absolute), any other number by
    itself."""
    if isinstance(tree, dict):
        return [x for name, value in tree.items() if name != "timings"
                for x in _numbers(value, name)]
    if key == "covariance":
        matrix = np.asarray(tree, dtype=float)
        sigma = np.sqrt(np.abs(np.diag(matrix)))
        return list(zip(matrix.ravel().tolist(), np.outer(sigma, sigma).ravel().tolist()))
    if key in ("matrix", "directions"):
        return [(value, 1.0) for value in np.ravel(np.asarray(tree, dtype=float)).tolist()]
    if isinstance(tree, list):
        return [x for value in tree for x in _numbers(value, key)]
    if isinstance(tree, int | float) and not isinstance(tree, bool):
        return [(float(tree), abs(float(tree)))]
    return []


def _assert_reports_equal(out, expected_out):
    """Every number of each project's results.json equal to `EQUAL_RTOL` of its scale
    (`_numbers`), since two compilations of one program may round an entry near zero
    differently (5.7e-17 on an ellipsoid direction's component of -4.3e-5, seen under the
    tests' XLA flags)."""
    for folder in sorted(p for p in expected_out.iterdir() if p.is_dir()):
        names = sorted(p.name for p in folder.iterdir())
        assert sorted(p.name for p in (out / folder.name).iterdir()) == names
        got = np.array(_numbers(json.loads((out / folder.name / "results.json").read_text())))
        want = np.array(_numbers(json.loads((folder / "results.json").read_text())))
        assert got.shape == want.shape, folder.name
        differ = np.abs(got[:, 0] - want[:, 0]) > EQUAL_RTOL * want[:, 1]
        assert not differ.any(), (folder.name, got[differ, 0], want[differ, 0])


def _abstract(batch):
    """What the compiled programs of a padded batch depend on: the static structure of its
    problem and plan, and the shape and dtype of every array."""
    arrays, static = eqx.partition((batch.problem, batch.plan), eqx.is_array)
    return (jax.tree_util.tree_structure(static), jax.tree_util.tree_leaves(static),
            [(a.shape, a.dtype) for a in jax.tree_util.tree_leaves(arrays)])


def test_chunks_of_a_group_share_one_compiled_shape(projects):
    """Two chunks of different projects, padded to their group's `batch_shape`, are alike
    to the compiler (one compilation per group and worker): blocks, observation rows, free
    indices and the linearisation plans' keys."""
    problems = [jaxba.build_project(jaxba.read_project(p)).problem for p in projects[:8]]
    shape = batch_shape(problems)
    first, second = (pad_problems(problems[:4], shape), pad_problems(problems[4:], shape))
    assert _abstract(first) == _abstract(second)
    assert list(second.n_free) == [p.n_unknowns() for p in problems[4:]]
    with pytest.raises(ValueError, match="cannot hold"):
        pad_problems(problems, batch_shape(problems[:1]))


def test_dask_batch_equals_the_in_process_batch(local, on_dask):
    (local_out, local_rows), (out, rows, lines) = local, on_dask
    assert [r["status"] for r in local_rows] == ["ok"] * N_PROJECTS
    assert local_rows[0]["C1.smac.c.std"] > 0
    _assert_rows_equal(rows, local_rows)
    _assert_reports_equal(out, local_out)
    assert any(line.startswith("solving on Dask scheduler") and "(2 workers" in line
               for line in lines)
    assert f"solving {N_PROJECTS} project(s) in {N_PROJECTS // CHUNK} padded batch(es)" in lines


def test_a_killed_worker_loses_no_project(cluster, projects, local, tmp_path):
    """A worker process killed (SIGKILL) while it solves a chunk: its chunks run again on the
    other worker (or its restarted successor). The killer watches from a thread started
    before the chunks are submitted, so that it sees the first ones in flight: waiting for
    a finished project first raced with the last chunks (all done before it looked, on a
    fast machine)."""
    _, client = cluster
    killed = []

    def kill_a_busy_worker():
        for _ in range(3000):  # 30 s: the chunks are submitted within milliseconds
            busy = [address for address, keys in client.processing().items() if keys]
            if busy:
                pids = client.run(os.getpid, workers=busy[:1])
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(busy[0])
                return
            time.sleep(0.01)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    try:
        rows = run_batch(projects, tmp_path / "out", scheduler=client, chunk_size=CHUNK)
    finally:
        killer.join()
    assert killed
    assert [r["status"] for r in rows] == ["ok"] * N_PROJECTS
    _assert_rows_equal(rows, local[1])
    client.wait_for_workers(2, timeout=60)  # the nanny restarted it, for the next tests


def test_resume_skips_finished_projects_on_a_scheduler_address(cluster, on_dask, tmp_path,
                                                               capsys):
    """`jaxba batch --resume --scheduler ADDRESS`: the 15 projects whose reports exist are
    not solved again (their files untouched, their rows read back from results.json); the 5
    others are."""
    the_cluster, _ = cluster
    dask_out, dask_rows, _ = on_dask
    out = tmp_path / "out"
    shutil.copytree(dask_out, out)
    redo = [f"p{k:02d}" for k in range(5)]  # all four sizes: the group's shape is unchanged
    for name in redo:
        shutil.rmtree(out / name)
    (out / "p05" / "p05.res").unlink()  # reports incomplete: solved again
    redo.append("p05")
    kept = {path: path.stat().st_mtime_ns for path in out.glob("p*/*")
            if path.parent.name not in redo}
    paths = [row["path"] for row in dask_rows]
    code = main(["batch", *paths, "--out", str(out), "--resume", "--chunk", str(CHUNK),
                 "--scheduler", the_cluster.scheduler_address])
    assert code == 0
    assert f"{N_PROJECTS} of {N_PROJECTS} projects converged" in capsys.readouterr().out
    assert {path: path.stat().st_mtime_ns for path in kept} == kept
    summary = json.loads((out / "summary.json").read_text())
    modes = ["batch" if row["name"] in redo else "resumed" for row in dask_rows]
    _assert_rows_equal(summary, dask_rows, modes=modes)
    for name in redo:
        assert (out / name / f"{name}.res").is_file()


def test_monte_carlo_on_dask_equals_in_process(cluster, projects):
    """7 replicates in chunks of 4 (the second filled up with a copy): 2 tasks on Dask."""
    _, client = cluster
    problem = jaxba.build_project(jaxba.read_project(projects[0])).problem
    key = jax.random.key(3)
    here = monte_carlo(problem, 7, key, at=problem.initial, chunk_size=4)
    there = monte_carlo(problem, 7, key, at=problem.initial, chunk_size=4, scheduler=client)
    assert there.free.shape == here.free.shape == (7, problem.n_unknowns())
    assert bool(np.all(there.solutions.converged))
    assert np.ptp(there.free, axis=0).max() > 0  # 7 different replicates
    np.testing.assert_allclose(there.free, here.free, rtol=EQUAL_RTOL, atol=0)
    np.testing.assert_allclose(there.covariance, here.covariance, rtol=1e-9,
                               atol=1e-12 * np.abs(here.covariance).max())


def test_scheduler_refused_before_any_work(projects, tmp_path, monkeypatch, capsys):
    """No Dask: exit 2 naming the extra to install, nothing read or written; a malformed
    local:N likewise."""
    out = tmp_path / "out"
    with monkeypatch.context() as patch:
        patch.setitem(sys.modules, "distributed", None)  # as if not installed
        assert main(["batch", str(projects[0]), "--out", str(out), "--scheduler",
                     "local:2"]) == 2
    assert "pip install 'jaxba[dask]'" in capsys.readouterr().err
    assert not out.exists()
    pytest.importorskip("distributed")
    for bad in ("local:0", "local:x", "   "):
        assert main(["batch", str(projects[0]), "--out", str(out), "--scheduler", bad]) == 2
        assert "scheduler" in capsys.readouterr().err
    check_scheduler("localhost:8786")  # an address, not "local"
    assert (local_workers("local:3"), local_workers("localhost:8786")) == (3, None)
    assert main(["batch", str(projects[0]), "--out", str(out), "--chunk", "0"]) == 2
    assert not out.exists()
