"""Batch adjustment: padded, vmapped solves equal single adjustments; `jaxba batch` with
failing projects; Monte Carlo and bootstrap replicates against the formal precision."""

import concurrent.futures
import dataclasses
import json
import math
import os
import pathlib
import shutil
import subprocess
import sys
import textwrap

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
from helpers import move_tie_points

import jaxba
from jaxba import _programs
from jaxba._adjust import _batch, _padding
from jaxba._adjust._batch import adjust_batch
from jaxba._adjust._montecarlo import bootstrap, monte_carlo
from jaxba._adjust._padding import pad_problems
from jaxba._cli import _batch_processes, _batch_run
from jaxba._cli._batch_read import finished_results, read_batch
from jaxba._cli._batch_run import run_batch
from jaxba._cli._batch_solve import Chunk, solve_chunk
from jaxba._cli._main import main
from jaxba._models._cameras import CAMERA_MODELS
from jaxba._problem._bundle import free_positions
from jaxba._report import write_reports
from jaxba._report._outputs import OBSERVATIONS_FILE, REPORT_SETS
from jaxba._solvers._solution import stop_reason
from jaxba._statistics._summary import variance_test

BATCH_RTOL = 1e-8  # each batch result equals the single adjustment to 1e-8 relative
SIZES = ((6, 20), (8, 26), (7, 30))  # (images, targets): three shapes padded to one
MC_STD_RTOL = 0.45  # empirical σ from 40 replicates: ±11 % (1σ) sampling error, 4σ


def _flat_close(a, b, rtol):
    a, b = jaxba.advanced.flatten(a), jaxba.advanced.flatten(b)
    scale = np.maximum(np.abs(b), 1e-12)
    return float(np.max(np.abs(a - b) / scale)) <= rtol


@pytest.fixture(scope="module")
def projects(tmp_path_factory):
    root = tmp_path_factory.mktemp("batch")
    paths = []
    for k, (n_images, n_targets) in enumerate(SIZES):
        truth = jaxba.write_synthetic_project(
            root / f"p{k}", name=f"p{k}", seed=40 + k, n_images=n_images, n_targets=n_targets
        )
        paths.append(truth.project_file)
    built = [jaxba.build_project(jaxba.read_project(p)) for p in paths]
    return root, paths, built


@pytest.fixture(scope="module")
def batch_and_single(projects):
    _, _, built = projects
    settings = built[0].spec.settings
    batch = adjust_batch(
        [p.problem for p in built], sigma0=settings.sigma0, max_steps=settings.max_iterations,
        rtol=settings.rtol, atol=settings.atol, alpha=settings.snooping_alpha,
        familywise=settings.snooping_familywise,
    )
    single = [jaxba.adjust_project(p) for p in built]
    return batch, single


def test_padding_keeps_structure(projects):
    _, _, built = projects
    batch = pad_problems([p.problem for p in built])
    assert batch.problem.initial.points.shape[:2] == (3, max(t for _, t in SIZES) + 1)
    assert list(batch.n_free) == [p.problem.n_unknowns() for p in built]
    assert list(batch.n_observations) == [p.problem.n_observations() for p in built]
    short = dataclasses.replace(_padding.batch_shape(batch.problems), free=max(batch.n_free) - 1)
    with pytest.raises(ValueError, match="cannot hold"):  # one more free unknown than room
        pad_problems(batch.problems, short)


def test_free_positions_of_stacked_masks_are_each_row_s_flatnonzero():
    """The padded free index (`free_positions`) of rows with different counts, against
    `np.flatnonzero` of each row; a row filling `length` exactly has no fill."""
    mask = np.random.default_rng(3).random((4, 17)) < 0.4
    mask[2] = False  # a problem with nothing free
    index = free_positions(mask, 12, fill=99)
    for row, positions in zip(mask, index):
        own = np.flatnonzero(row)
        np.testing.assert_array_equal(positions[: own.size], own)
        assert np.all(positions[own.size:] == 99)
    full = int(mask[0].sum())
    np.testing.assert_array_equal(free_positions(mask[:1], full, fill=99)[0],
                                  np.flatnonzero(mask[0]))


def test_problems_freeing_different_iops_batch_like_single_solves(projects):
    """One padded plan serves problems whose free IOPs differ (P2 fixed in one).

    The three problems pad to the shape of the unmodified batch (the third frees the most
    unknowns), so the batch solve is the one the other tests compile; the single solves
    run step by step, as `adjust` does, sharing its programs for the unmodified problems."""
    _, _, built = projects
    problems = [p.problem for p in built]
    free = np.array(problems[1].free.cameras["smac"])
    p2 = list(jaxba.SmacCamera.parameter_names).index("P2")
    assert free[0, p2]
    free[0, p2] = False
    problems[1] = eqx.tree_at(lambda p: p.free.cameras["smac"], problems[1], jnp.asarray(free))
    batch = pad_problems(problems)
    solutions = jaxba.advanced.solve_batch(batch.problem, batch.plan)
    for k, problem in enumerate(problems):
        single = jaxba.solve(problem, on_step=lambda step: None)
        padded = jax.tree.map(lambda leaf: leaf[k], solutions.parameters)
        np.testing.assert_allclose(
            np.asarray(padded.cameras["smac"]), np.asarray(single.parameters.cameras["smac"]),
            rtol=BATCH_RTOL, atol=0)
    assert float(solutions.parameters.cameras["smac"][1, 0, p2]) == float(
        problems[1].initial.cameras["smac"][0, p2])


@pytest.mark.slow  # three single adjustments: one compilation each
def test_batch_equals_single_adjustment(batch_and_single):
    batch, single = batch_and_single
    for b, s in zip(batch, single):
        assert b.converged and s.converged
        # Only the start and the solution are kept, numbered as the single adjustment's.
        assert b.n_iterations == s.n_iterations > 1 and b.steps == s.steps
        assert [it.iteration for it in b.iterations] == [0, s.n_iterations]
        assert b.iterations[-1].cost == pytest.approx(s.iterations[-1].cost, rel=BATCH_RTOL)
        assert _flat_close(b.parameters, s.parameters, BATCH_RTOL)
        assert _flat_close(b.precision.std, s.precision.std, BATCH_RTOL)
        assert b.precision.redundancy == s.precision.redundancy
        assert b.sigma0 == pytest.approx(s.sigma0, rel=BATCH_RTOL)
        covariance = s.precision.covariance
        np.testing.assert_allclose(b.precision.covariance, covariance, rtol=1e-6,
                                   atol=BATCH_RTOL * np.abs(covariance).max())
        for rb, rs in zip(b.reliability.redundancy_numbers, s.reliability.redundancy_numbers):
            np.testing.assert_allclose(rb, rs, rtol=0, atol=BATCH_RTOL)
        for vb, vs in zip(b.residuals, s.residuals):
            np.testing.assert_allclose(vb, vs, rtol=0, atol=BATCH_RTOL * np.abs(vs).max())


def test_run_batch_reports_and_failures(projects, tmp_path):
    root, paths, _ = projects
    broken = root / "broken.toml"
    broken.write_text("[project\nname = 'x'\n")
    defect = jaxba.write_synthetic_project(root / "free", name="free", seed=3, n_images=6,
                                           n_targets=20, datum="none", n_distances=0)
    out = tmp_path / "out"
    lines, finished = [], []
    rows = run_batch([*paths, broken, defect.project_file], out, progress=lines.append,
                     advance=lambda: finished.append(len(lines)))
    assert [r["status"] for r in rows] == ["ok", "ok", "ok", "failed", "failed"]
    assert "datum" in rows[4]["reason"] and "broken.toml" in rows[3]["reason"]
    for k in range(3):
        assert (out / f"p{k}" / "results.json").exists() and (out / f"p{k}" / f"p{k}.out").exists()
        assert rows[k]["C1.smac.c.std"] > 0
    summary = json.loads((out / "summary.json").read_text())
    assert [r["name"] for r in summary[:3]] == ["p0", "p1", "p2"]
    header = (out / "summary.csv").read_text().splitlines()[0].split(",")
    assert {"name", "status", "converged", "sigma0", "C1.smac.c", "C1.smac.c.std",
            "variance_test.statistic", "variance_test.passed"} <= set(header)
    assert any(line.startswith("[3/4]") or line.startswith("[4/4]") for line in lines)
    assert len(finished) == 5  # every project once, the one that failed to read included


def test_tables_read_where_the_projects_are_adjusted(projects, tmp_path):
    """`read_batch(tables=False)` (the command line's) reads only the project files; each
    project's tables are read where it is adjusted: a broken table fails that project
    alone, with the reader's message, and the others get the rows of a batch read whole."""
    root, paths, _ = projects
    folder = root / "bad_table"
    shutil.copytree(paths[0].parent, folder)
    toml = folder / paths[0].name
    toml.write_text(toml.read_text().replace('name = "p0"', 'name = "bad_table"', 1))
    with (folder / "ground_points.txt").open("a") as table:
        table.write("extra 1.0 2.0\n")  # a point one coordinate short
    entries = read_batch([*paths, toml], tmp_path / "lazy", tables=False)
    assert [(e.status, e.spec, e.name) for e in entries] == [
        ("pending", None, "p0"), ("pending", None, "p1"), ("pending", None, "p2"),
        ("pending", None, "bad_table")]
    lazy = run_batch([*paths, toml], tmp_path / "lazy", entries=entries)
    whole = run_batch(paths, tmp_path / "whole")
    assert [r["status"] for r in lazy] == ["ok", "ok", "ok", "failed"]
    assert "ground_points.txt:" in lazy[3]["reason"] and "expected" in lazy[3]["reason"]
    for a, b in zip(whole, lazy[:3]):
        assert a.keys() == b.keys()
        for key, value in a.items():
            if isinstance(value, float):
                assert b[key] == pytest.approx(value, rel=BATCH_RTOL, abs=1e-12), key
            else:
                assert b[key] == value, key


def test_free_networks_are_adjusted_alone_in_a_batch(projects, tmp_path):
    """A free network's inner constraints tie every unknown in its own order, which a padded
    chunk does not keep: `jaxba batch` adjusts each alone ("single"), beside the batched
    projects, with `adjust_project`'s estimates and σ."""
    _, paths, _ = projects
    free = []
    for k in range(2):
        truth = jaxba.write_synthetic_project(tmp_path / f"free{k}", name=f"free{k}",
                                              seed=10 + k, n_images=6, n_targets=20)
        text = truth.project_file.read_text()
        truth.project_file.write_text(text.replace("[adjustment]", '[adjustment]\ndatum = "free"'))
        free.append(truth.project_file)
    rows = run_batch([*free, *paths], tmp_path / "out")
    assert [(row["status"], row["mode"]) for row in rows] == [("ok", "single")] * 2 + [
        ("ok", "batch")] * len(paths)
    for path, row in zip(free, rows):
        alone = jaxba.adjust_project(jaxba.build_project(jaxba.read_project(path)))
        assert row["sigma0"] == pytest.approx(float(alone.sigma0), rel=1e-12)
        assert row["C1.smac.c.std"] == pytest.approx(
            float(np.asarray(alone.precision.std.cameras["smac"])[0, 2]), rel=1e-9)


def test_a_batched_project_stopped_by_its_step_limit_says_so(projects):
    """Stopped by `max_steps`, a batched adjustment says why in the single adjustment's words
    (`stop_reason`), not optimistix's code read as "unknown"."""
    _, _, built = projects
    for result in adjust_batch([p.problem for p in built[:2]], max_steps=1):
        assert not result.converged
        assert result.message == "the maximum number of steps (1) was reached"


@pytest.mark.slow  # the diverging project's own solve, compiled for its shape
def test_a_project_that_does_not_converge_in_its_batch_is_adjusted_alone(projects, tmp_path):
    """A batched solve keeps no iterations, so it cannot tell a solve stuck far from the
    solution from one cut short: a project that stops unconverged in its batch is adjusted
    again alone, and its row and reports say what `jaxba adjust` says (which approximations
    it diverged from). Here its tie points lie 5 m off (the network is 4 m across)."""
    _, paths, _ = projects
    folder = tmp_path / "diverging"
    shutil.copytree(paths[0].parent, folder)
    project = folder / paths[0].name
    project.write_text(project.read_text().replace('name = "p0"', 'name = "diverging"', 1))
    move_tie_points(folder / "ground_points.txt", 5.0)
    lines = []
    rows = run_batch([*paths[1:], project], tmp_path / "out", progress=lines.append)
    alone = jaxba.adjust_project(jaxba.build_project(jaxba.read_project(project)))
    assert not alone.converged and "diverged from the approximations" in alone.message
    assert [(row["status"], row["mode"]) for row in rows] == [("ok", "batch")] * 2 + [
        ("not converged", "single")]
    assert rows[2]["reason"] == alone.message
    assert rows[2]["sigma0"] == pytest.approx(float(alone.sigma0), rel=1e-9)
    assert "diverging: not converged in its batch; adjusting it alone" in lines
    results = json.loads((tmp_path / "out" / "diverging" / "results.json").read_text())
    assert results["message"] == alone.message and len(results["iterations"]) > 2


def test_a_stop_reason_read_from_the_host_names_it():
    """A solve's result moved to the host (a NumPy scalar value, as a batch's is) is read
    like one on the device."""
    on_host = jax.tree.map(lambda value: np.asarray(value)[()], optx.RESULTS.nonfinite)
    assert isinstance(jax.tree.leaves(on_host)[0], np.generic)
    assert stop_reason(on_host, 9) == optx.RESULTS[optx.RESULTS.nonfinite] != "unknown"
    reached = jax.tree.map(lambda value: np.asarray(value)[()],
                           optx.RESULTS.nonlinear_max_steps_reached)
    assert stop_reason(reached, 9) == "the maximum number of steps (9) was reached"


def test_projects_with_different_ties_are_padded_apart(projects, tmp_path):
    """A padded chunk holds one set of ties: projects whose ties differ are of different
    kinds (`batch_kind`), so `jaxba batch` pads them apart, each batched, none failed and
    retried alone; the tied parameter takes its source's value, as `adjust_project` gives."""
    _, paths, _ = projects
    folder = tmp_path / "tied"
    shutil.copytree(paths[1].parent, folder)
    cameras = folder / "cameras.toml"
    free = 'free = ["xp", "yp", "c", "K1", "K2", "K3", "P1", "P2"]'
    assert free in cameras.read_text()
    cameras.write_text(cameras.read_text().replace(
        free, free.replace(', "P2"', "") + '\nties = { P2 = "P1" }'))
    tied = folder / paths[1].name
    lines = []
    rows = run_batch([paths[0], tied, paths[2]], tmp_path / "out", progress=lines.append)
    assert not any("failed" in line for line in lines), lines
    assert [(row["status"], row["mode"]) for row in rows] == [("ok", "batch")] * 3
    assert rows[1]["C1.smac.P2"] == rows[1]["C1.smac.P1"] != 0
    alone = jaxba.adjust_project(jaxba.build_project(jaxba.read_project(tied)))
    assert rows[1]["sigma0"] == pytest.approx(float(alone.sigma0), rel=1e-10)


class _StartedAfter:
    """A stand-in for `Workers.starter`: done once asked `n` times."""

    def __init__(self, n: int):
        self.asked, self.n = 0, n

    def done(self) -> bool:
        self.asked += 1
        return self.asked > self.n


def test_tables_are_read_here_while_the_workers_start(projects, tmp_path):
    """While the worker processes start, the caller reads the tables of the shares' projects,
    one of each share in turn, and stops once they are started; a project whose table it
    cannot read is left unread, for its worker to fail with the reader's message."""
    root, paths, _ = projects
    folder = root / "unreadable_table"
    shutil.copytree(paths[0].parent, folder)
    toml = folder / paths[0].name
    toml.write_text(toml.read_text().replace('name = "p0"', 'name = "unreadable_table"', 1))
    (folder / "ground_points.txt").write_bytes(b"\xff\xfe not text")
    entries = read_batch([*paths, toml], tmp_path / "out", tables=False)
    parts = _batch_processes.shares(entries, 2)
    assert [[e.name for e in part] for part in parts] == [["p0", "p1"], ["p2", "unreadable_table"]]
    _batch_processes._read_while_starting(parts, _StartedAfter(2))
    assert [e.spec is not None for e in entries] == [True, False, True, False]
    _batch_processes._read_while_starting(parts, _StartedAfter(100))
    assert [e.spec is not None for e in entries] == [True, True, True, False]
    rows = run_batch([*paths, toml], tmp_path / "out", entries=entries)
    assert [r["status"] for r in rows] == ["ok", "ok", "ok", "failed"]
    assert "ground_points.txt" in rows[3]["reason"]


def test_a_worker_that_cannot_start_stops_the_batch_with_its_error():
    """The workers are started on a thread; what stopped a start is raised by
    `Workers.ready`, before any share is handed out."""

    class Broken:
        def submit(self, function):
            raise OSError("no forkserver")

    starter = concurrent.futures.Future()
    _batch_processes._start_all(Broken(), 2, starter)
    workers = _batch_processes.Workers(Broken(), None, 2, starter)
    with pytest.raises(OSError, match="no forkserver"):
        workers.ready()


@pytest.mark.slow
def test_cli_batch_exit_code(projects, tmp_path, capsys):
    _, paths, _ = projects
    # All three: the batch that run_batch solves in the test above (its programs compiled).
    assert main(["batch", *map(str, paths), "--out", str(tmp_path / "cli"), "--progress"]) == 0
    out = capsys.readouterr().out
    assert "3 of 3 projects converged" in out
    assert "3/3" in out  # the bar, asked for although stdout is not a terminal


@pytest.mark.slow
def test_monte_carlo_and_bootstrap_against_formal(projects):
    _, _, built = projects
    problem = built[1].problem
    formal = jaxba.adjust(problem, check=False)
    index = jaxba.advanced.free_indices(problem)
    formal_std = jaxba.advanced.flatten(formal.precision.std)[index]
    for replicates in (monte_carlo(problem, 40, jax.random.key(0)),
                       bootstrap(problem, 40, jax.random.key(1))):
        assert bool(np.all(replicates.solutions.converged))
        empirical = jaxba.advanced.flatten(replicates.std)[index]
        ratio = empirical / formal_std
        # Monte Carlo noise has σ; σ̂0 of this sample is ≈ 1, so formal ≈ empirical.
        assert np.median(ratio) == pytest.approx(1.0, rel=0.15)
        assert np.all(np.abs(ratio - 1) < MC_STD_RTOL), ratio
    assert math.isfinite(formal.sigma0)


# Last: its chunked program takes the process past conftest's 1 GiB, where jax's in-memory
# caches are cleared; before the tests above, they reloaded their programs from disk.
def test_chunked_batch_equals_one_vmapped_batch(projects):
    """chunk_size splits the batch into vmapped chunks run one after the other (the last
    one short): the solutions are those of one vmapped call."""
    _, _, built = projects
    batch = pad_problems([p.problem for p in built])
    whole = jaxba.advanced.solve_batch(batch.problem, batch.plan)
    chunked = jaxba.advanced.solve_batch(batch.problem, batch.plan, chunk_size=2)
    assert bool(jnp.all(whole.converged)) and bool(jnp.all(chunked.converged))
    np.testing.assert_array_equal(np.asarray(chunked.steps), np.asarray(whole.steps))
    for k in range(len(built)):
        assert _flat_close(jax.tree.map(lambda leaf: leaf[k], chunked.parameters),
                           jax.tree.map(lambda leaf: leaf[k], whole.parameters), BATCH_RTOL)


def test_summary_names_parameters_by_model_and_tests_the_variance_factor(
        projects, batch_and_single, tmp_path):
    """summary rows: `<camera>.<model>.<parameter>` columns and the χ² test of σ̂0, each equal
    to the single adjustment's (`variance_test`, the test of NAME.out and results.json)."""
    _, paths, built = projects
    _, single = batch_and_single
    rows = run_batch(paths, tmp_path / "out")
    for row, project, result in zip(rows, built, single):
        test = variance_test(result)
        assert row["variance_test.alpha"] == test.alpha
        for key in ("statistic", "low", "high"):
            assert row[f"variance_test.{key}"] == pytest.approx(getattr(test, key),
                                                                rel=BATCH_RTOL)
        assert row["variance_test.passed"] == test.passed
        assert row["variance_test.passed"] == (
            row["variance_test.low"] <= row["variance_test.statistic"] <= row["variance_test.high"])
        for camera_id, (model, index) in project.camera_rows.items():
            names = CAMERA_MODELS[model].parameter_names
            values = np.asarray(result.parameters.cameras[model])[index]
            for name, value in zip(names, values):
                assert row[f"{camera_id}.{model}.{name}"] == pytest.approx(
                    value, rel=BATCH_RTOL, abs=1e-12)
        assert not [key for key in row if key.startswith("C1.") and key.count(".") < 2]


def test_batch_reports_are_those_of_one_project_s_writer(projects, tmp_path):
    """Every report `run_batch` writes for a project (`write_batch_reports`: not checked
    again, not flushed file by file) is byte for byte what `write_reports` writes for the
    same adjustment (its chunk solved again alike), and nothing else is left beside them."""
    _, paths, built = projects
    run_batch(paths, tmp_path / "batch")
    outcomes = solve_chunk(Chunk(tuple(built), size=len(built)))
    for project, outcome in zip(built, outcomes):
        single = write_reports(project, outcome.result, tmp_path / "single" / project.spec.name)
        folder = tmp_path / "batch" / project.spec.name
        assert sorted(path.name for path in folder.iterdir()) == sorted(p.name for p in single)
        for path in single:
            assert (folder / path.name).read_bytes() == path.read_bytes(), path.name
    # --resume trusts all five reports, none empty (what a system crash can leave of them).
    entries = read_batch(paths, tmp_path / "batch")
    assert all(finished_results(entry) is not None for entry in entries)
    (tmp_path / "batch" / "p1" / "p1.out").write_bytes(b"")
    assert [finished_results(entry) is None for entry in entries] == [False, True, False]


def test_compact_reports_leave_out_the_files_of_a_row_per_observation(projects, tmp_path):
    """`--reports compact`: each project gets NAME.out, NAME.sigma and results.json, byte for
    byte those of all reports (the same chunks), and neither NAME.res nor observations.csv;
    `resume` trusts a compact set where compact reports are asked for, and adjusts those
    projects again where all are."""
    _, paths, _ = projects
    rows = run_batch(paths, tmp_path / "all")
    assert main(["batch", *map(str, paths), "--out", str(tmp_path / "compact"),
                 "--reports", "compact"]) == 0
    for row in rows:
        name, folder = row["name"], tmp_path / "compact" / row["name"]
        written = sorted(path.name for path in folder.iterdir())
        assert written == sorted([f"{name}.out", f"{name}.sigma", "results.json"])
        for file in written:
            assert (folder / file).read_bytes() == (tmp_path / "all" / name / file).read_bytes()
    again = run_batch(paths, tmp_path / "compact", reports="compact", resume=True)
    assert [row["mode"] for row in again] == ["resumed"] * len(paths)
    whole = run_batch(paths, tmp_path / "compact", resume=True)
    assert [row["mode"] for row in whole] == ["batch"] * len(paths)
    assert (tmp_path / "compact" / "p0" / OBSERVATIONS_FILE).is_file()
    with pytest.raises(ValueError, match="'some': one of all, compact"):
        run_batch(paths, tmp_path / "some", reports="some")


def test_the_command_line_offers_every_set_of_reports(tmp_path, capsys):
    assert main(["batch", "p.toml", "--out", str(tmp_path), "--reports", "some"]) == 2
    error = capsys.readouterr().err
    assert "--reports" in error and all(f"'{name}'" in error for name in REPORT_SETS)


@pytest.mark.slow  # two worker processes, each starting jax
def test_worker_processes_give_the_rows_and_reports_of_one_process(projects, tmp_path,
                                                                   monkeypatch):
    """`jobs=2`: two worker processes each adjust a share from end to end (a project that
    cannot be read and one with a datum defect fail alone, in their share); the rows equal
    those of one process (to rounding: the chunks differ), every report is written, every
    project is said finished once and each worker's lines reach the caller."""
    root, paths, _ = projects
    broken = root / "broken_share.toml"
    broken.write_text("[project\nname = 'x'\n")
    defect = jaxba.write_synthetic_project(root / "free_share", name="free_share", seed=3,
                                           n_images=6, n_targets=20, datum="none",
                                           n_distances=0)
    batch = [*paths, defect.project_file, broken]
    alone = run_batch(batch, tmp_path / "alone")
    monkeypatch.setattr(_batch_run, "SHARE", 1)
    lines, finished = [], []
    shared = run_batch(batch, tmp_path / "shared", jobs=2, progress=lines.append,
                       advance=lambda: finished.append(1))
    assert "adjusting on 2 worker processes" in lines
    assert sum(line.startswith("solving") for line in lines) == 2
    assert len(finished) == len(batch)
    assert [r["status"] for r in shared] == [r["status"] for r in alone] == [
        "ok", "ok", "ok", "failed", "failed"]
    assert shared[3]["reason"] == alone[3]["reason"] and "datum" in shared[3]["reason"]
    for a, b in zip(alone[:3], shared[:3]):
        assert a.keys() == b.keys() and b["mode"] == "batch"
        for key, value in a.items():
            if isinstance(value, float) and key != "variance_test.alpha":
                assert b[key] == pytest.approx(value, rel=BATCH_RTOL, abs=1e-12), key
        folder = tmp_path / "shared" / a["name"]
        assert (folder / "results.json").is_file() and (folder / f"{a['name']}.out").is_file()
    assert json.loads((tmp_path / "shared" / "summary.json").read_text())[0]["name"] == "p0"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a forkserver on Linux only")
def test_workers_are_forked_from_a_server_that_imports_the_pipeline_once():
    """On Linux the workers are not started afresh: they are forked from a forkserver that
    was told to import the pipeline (`PRELOAD`) before forking them."""
    with _batch_processes.worker_processes(2) as workers:
        parents = {workers.pool.submit(os.getppid).result() for _ in range(4)}
    (server,) = parents  # both workers, one parent
    assert server != os.getpid()
    command = pathlib.Path(f"/proc/{server}/cmdline").read_bytes().decode()
    assert "forkserver" in command
    assert all(module in command for module in _batch_processes.PRELOAD)


def test_the_forkserver_ends_without_the_interpreter_s_clean_up(tmp_path):
    """The forkserver holds the caller's stdout and stderr until it ends, so a reader of the
    batch's output waits for it: it leaves with `os._exit` once the caller has ended. An exit
    handler that a module imported before the pipeline registers (so it would run after the
    quick exit's) never runs; the module was imported there (its other file exists)."""
    imported, cleaned_up = tmp_path / "imported", tmp_path / "cleaned_up"
    (tmp_path / "exit_marker.py").write_text(
        f"import atexit, pathlib\npathlib.Path({str(imported)!r}).touch()\n"
        f"atexit.register(pathlib.Path({str(cleaned_up)!r}).touch)\n")
    caller = tmp_path / "caller.py"
    caller.write_text(textwrap.dedent("""
        import os
        from jaxba._cli import _batch_processes
        _batch_processes.PRELOAD = ("exit_marker", *_batch_processes.PRELOAD)
        if __name__ == "__main__":
            with _batch_processes.worker_processes(2) as workers:
                print(workers.pool.submit(os.getppid).result())
    """))
    # Its output read to the end: the caller and the forkserver have both ended. (The
    # forkserver finds exit_marker through PYTHONPATH: Python 3.11's ignores the caller's
    # sys.path.)
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(tmp_path), *filter(None, [os.environ.get("PYTHONPATH")])])}
    done = subprocess.run([sys.executable, str(caller)], capture_output=True, text=True,
                          timeout=300, env=environment)
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) != 0 and imported.exists()
    assert not cleaned_up.exists()


def test_a_mixed_batch_compiles_one_program_per_kind(projects, tmp_path, monkeypatch):
    """Three projects of three sizes, one per chunk: padded to one shape, they are solved by
    one compiled program (traced once and stored once), not one per size."""
    _, paths, _ = projects
    monkeypatch.setattr(_programs, "_cache_folder", lambda: tmp_path)
    monkeypatch.setattr(_programs, "_loaded", {})
    traced = []

    def counted(*args, **kwargs):
        traced.append(1)
        return statistics_one(*args, **kwargs)

    statistics_one = _batch._statistics_one
    monkeypatch.setattr(_batch, "_statistics_one", counted)
    jax.clear_caches()
    rows = run_batch(paths, tmp_path / "out", chunk_size=1)
    assert [row["mode"] for row in rows] == ["batch"] * 3
    assert len(traced) == 1
    assert len(list((tmp_path / _programs.FOLDER).glob("batch_adjust-*"))) == 1


def test_the_datum_screen_passes_a_defined_datum_and_flags_a_defect():
    """`_datum_suspect` (the batch's screen, a shifted Cholesky): a full-rank N passes, padded
    too; a rank defect, an unobserved unknown or a NaN is left to `check_datum`."""
    j = np.random.default_rng(0).normal(size=(60, 8))
    j[:, 5] *= 1e-4  # badly scaled, well conditioned once equilibrated
    assert not bool(_batch._datum_suspect(jnp.asarray(j.T @ j), 8, 1e-9))
    defect = j.copy()
    defect[:, 7] = defect[:, 0] - 2 * defect[:, 1]  # s_min/s_max ~ 1e-16
    assert bool(_batch._datum_suspect(jnp.asarray(defect.T @ defect), 8, 1e-9))
    padded = np.zeros((10, 10))
    padded[:8, :8] = j.T @ j
    assert not bool(_batch._datum_suspect(jnp.asarray(padded), 8, 1e-9))
    assert bool(_batch._datum_suspect(jnp.asarray(padded), 9, 1e-9))  # unknown 9 unobserved
    padded[2, 3] = np.nan
    assert bool(_batch._datum_suspect(jnp.asarray(padded), 8, 1e-9))


def test_batched_datum_check_equals_check_datum(projects, tmp_path):
    """The batched datum screen lets the good projects through and gives a defective one the
    error `check_datum` raises for it alone (no control, scale from the distances: the six
    defects of a rigid motion)."""
    _, _, built = projects
    defect = jaxba.write_synthetic_project(tmp_path / "free", name="free", seed=3, n_images=6,
                                           n_targets=20, datum="none")
    free = jaxba.build_project(jaxba.read_project(defect.project_file))
    batch = [p.problem for p in built] + [free.problem]
    assert len({_padding.batch_kind(problem) for problem in batch}) == 1
    errors = jaxba.check_datum_batch(batch, labels=[p.labels for p in [*built, free]])
    assert errors[:3] == [None, None, None]
    with pytest.raises(jaxba.DatumError) as alone:
        jaxba.check_datum(free.problem, labels=free.labels)
    assert isinstance(errors[3], jaxba.DatumError) and str(errors[3]) == str(alone.value)
