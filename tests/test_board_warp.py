"""A calibration board's warp (mrcal's z = kx (1 - x²) + ky (1 - y²)): the model against
mrcal's definition, its derivatives against central differences, and synthetic calibrations
of a 300 mm x 188 mm board bent by about a millimetre: kx, ky recovered within their σ over
seeds (Monte Carlo), a flat board's consistent with 0, and σ̂0 of the bent board's data far
above 1 when the board is taken as flat. The project key (`board_warp`), its refusals, the
backends (dense only: the Schur path refuses it) and `jaxba batch` (adjusted alone)."""

import json
import pathlib

import equinox as eqx
import jax
import numpy as np
import pytest
import scipy.stats
from board_scene import COLS, ROWS, board, write_project
from helpers import FD_ATOL, FD_RTOL, central_difference, synthetic_rig

import jaxba
from jaxba._adjust._padding import pad_problems
from jaxba._models._board_warp import board_extent, warp_shape, warped_point
from jaxba._problem._linearisation import dense_jacobian
from jaxba._problem._observations import ImagePoints
from jaxba._problem._parameters import flatten, unflatten
from jaxba._solvers._schur._choice import use_schur

SPACING = 37.5  # mm: a 9 x 6 corner board 300 mm x 187.5 mm
WARP = (1.0, -0.7)  # kx, ky, mm
MRCAL_TOL = 1e-12  # mm, the same formula evaluated two ways
# Central differences in kx, ky: residuals whitened by 0.3 px reach ~1e3 with the poses moved,
# so the helpers' step (1e-6) leaves rounding of ~1e-16 * 1e3 / 1e-6 = 1e-7; a 1e-3 mm step
# leaves 1e-10, and a millimetre's curvature of the projection in Z far less truncation.
WARP_FD_STEP = 1e-3  # mm
SEEDS = range(6)
MC_ALPHA = 1e-3  # the Monte Carlo's χ² test of (k - truth) / σ over all seeds
SIGMAS = 3.5  # every single estimate within 3.5 σ of the truth (2 x 6 tests at 4.7e-4 each)
VARIANCE_ALPHA = 1e-3  # the one-sided χ² test of σ̂0 against σ0 = 1 (the noise's σ)


def _points_and_shape(spacing=SPACING):
    """The flat board's corners (n, 3) and their `warp_shape` (n, 2)."""
    flat = board(spacing)
    return flat, warp_shape(flat[:, :2], board_extent(flat[:, :2]))


def test_warp_is_mrcals_formula():
    """(1 - x²) over the board's extent is mrcal's 4 x_r (1 - x_r), x_r = column / (W - 1)
    (its `ref_calibration_object`), written out here from grid indices; the board scene's
    bent corners are the flat ones moved by `warped_point`."""
    flat, shape = _points_and_shape()
    cols, rows = np.meshgrid(np.arange(COLS), np.arange(ROWS))
    xr, yr = cols.ravel() / (COLS - 1), rows.ravel() / (ROWS - 1)
    np.testing.assert_allclose(shape, np.column_stack([4 * xr * (1 - xr), 4 * yr * (1 - yr)]),
                               rtol=0, atol=MRCAL_TOL)
    moved = jax.vmap(warped_point, in_axes=(0, None, 0))(flat, np.array(WARP), shape)
    np.testing.assert_allclose(np.asarray(moved), board(SPACING, WARP), rtol=0, atol=MRCAL_TOL)
    assert shape.min() == 0 and shape.max() == pytest.approx(1, abs=0.02)  # edges, centre


def test_warp_equals_mrcals_own():
    """Against mrcal itself, where it is installed (not a dependency)."""
    mrcal = pytest.importorskip("mrcal")
    flat, shape = _points_and_shape()
    reference = mrcal.ref_calibration_object(COLS, ROWS, SPACING,
                                             calobject_warp=np.array(WARP))
    moved = jax.vmap(warped_point, in_axes=(0, None, 0))(flat, np.array(WARP), shape)
    np.testing.assert_allclose(np.asarray(moved), np.reshape(reference, (-1, 3)), rtol=0,
                               atol=MRCAL_TOL)


def test_a_board_of_one_row_is_refused():
    with pytest.raises(ValueError, match="rectangle"):
        board_extent(np.column_stack([np.arange(5.0), np.zeros(5)]))


@pytest.fixture(scope="module")
def bent(tmp_path_factory):
    """(project, result) of seed 0's bent board with its warp free."""
    out = tmp_path_factory.mktemp("bent")
    file = write_project(out, 0, spacing=SPACING, warp=WARP, board_warp=True, name="bent")
    project = jaxba.build_project(jaxba.read_project(file))
    return project, jaxba.adjust_project(project)


def test_warp_derivatives_match_central_differences(bent):
    """d residuals / d (kx, ky) of the image rows (`row_jacobians`, and the dense Jacobian's
    columns built from them) against central differences of the residuals, at a warp and
    poses away from the solution."""
    project, _ = bent
    problem = project.problem
    params = jax.tree.map(np.asarray, problem.initial)
    params = unflatten(params, flatten(params))  # NumPy copies
    params.warp[:] = [[0.8, -0.5]]
    params.images[:, :3] += 3.0
    (group,) = [g for g in problem.groups if isinstance(g, ImagePoints)]

    def residuals(warp):
        moved = unflatten(params, flatten(params))
        moved.warp[:] = warp
        return np.asarray(group.residuals(moved, problem.refraction))

    numeric = central_difference(residuals, params.warp, WARP_FD_STEP)[..., 0, :]  # (n, 2, 2)
    _, blocks = group.row_jacobians(params, problem.refraction)
    np.testing.assert_allclose(np.asarray(blocks)[:, :, -2:], numeric, rtol=FD_RTOL,
                               atol=FD_ATOL)
    assert np.abs(numeric).max() > 0.1  # a millimetre of warp moves the image points
    jacobian, _ = dense_jacobian(problem, params)
    positions = unflatten(params, np.arange(flatten(params).size))
    columns = np.searchsorted(np.flatnonzero(flatten(problem.free)),
                              np.asarray(positions.warp).ravel())
    np.testing.assert_allclose(jacobian[:, columns], numeric.reshape(-1, 2), rtol=FD_RTOL,
                               atol=FD_ATOL)


def test_rig_rows_carry_the_warp_after_the_mount():
    """Rows of rig cameras (IOPs, frame, mount, point, then kx, ky): the warp's columns
    against central differences, every other column that of the same rows without a warp
    at the moved points (the warp changes nothing but where the point is)."""
    problem, _ = synthetic_rig()
    (group,) = problem.groups
    points = np.asarray(problem.initial.points)
    shape = warp_shape(points[:, :2], board_extent(points[:, :2]))
    warped = eqx.tree_at(lambda g: (g.board, g.warp_shape), group,
                         (np.zeros(group.point.shape[0], dtype=int),
                          shape[np.asarray(group.point)]), is_leaf=lambda leaf: leaf is None)
    warp = np.array([[0.6, -0.4]])
    params = eqx.tree_at(lambda p: p.warp, problem.initial, warp,
                         is_leaf=lambda leaf: leaf is None)
    refraction = problem.refraction

    def residuals(values):
        moved = eqx.tree_at(lambda p: p.warp, params, values)
        return np.asarray(warped.residuals(moved, refraction))

    numeric = central_difference(residuals, warp, WARP_FD_STEP)[..., 0, :]
    residual, blocks = warped.row_jacobians(params, refraction)
    blocks = np.asarray(blocks)
    np.testing.assert_allclose(blocks[:, :, -2:], numeric, rtol=FD_RTOL, atol=FD_ATOL)
    moved = eqx.tree_at(lambda p: p.points, problem.initial,
                        points + np.outer(shape @ warp[0], [0, 0, 1]))
    plain_residual, plain = group.row_jacobians(moved, refraction)
    assert blocks.shape[2] == plain.shape[2] + 2 == 10 + 12 + 3 + 2
    np.testing.assert_allclose(blocks[:, :, :-2], plain, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(residual, plain_residual, rtol=1e-12, atol=1e-12)


def _warp_estimates(tmp_path: pathlib.Path, warp) -> np.ndarray:
    """(seeds, 2, 2): kx, ky and their σ of the board bent by `warp`, one calibration per
    seed (the same shapes: one compiled program for all)."""
    out = []
    for seed in SEEDS:
        file = write_project(tmp_path / str(seed), seed, spacing=SPACING, warp=warp,
                             board_warp=True, name="mc")
        project = jaxba.build_project(jaxba.read_project(file))
        result = jaxba.adjust_project(project)
        assert result.converged
        out.append([np.ravel(result.parameters.warp), np.ravel(result.precision.std.warp)])
    return np.array(out)


def _assert_within_sigma(estimates: np.ndarray, truth) -> None:
    z = (estimates[:, 0] - np.asarray(truth)) / estimates[:, 1]
    assert np.all(np.abs(z) < SIGMAS), z
    chi2 = float(np.sum(z ** 2))
    dof = z.size
    low, high = scipy.stats.chi2.ppf([MC_ALPHA / 2, 1 - MC_ALPHA / 2], dof)
    assert low < chi2 < high, (chi2, dof)


@pytest.mark.slow
def test_monte_carlo_recovers_the_warp_within_sigma(tmp_path):
    """Six calibrations of the bent board (kx 1 mm, ky -0.7 mm, 0.3 px noise): every kx, ky
    within 3.5 σ of the truth, and Σ z² over all twelve a χ²(12) at 99.9 %."""
    estimates = _warp_estimates(tmp_path, WARP)
    _assert_within_sigma(estimates, WARP)
    assert np.all(estimates[:, 1] < 0.2)  # σ of about 0.1 mm: the warp at ~10 σ


@pytest.mark.slow
def test_a_flat_board_gives_a_warp_consistent_with_zero(tmp_path):
    _assert_within_sigma(_warp_estimates(tmp_path, (0.0, 0.0)), (0.0, 0.0))


def test_the_warp_fixed_leaves_the_bent_board_in_the_residuals(bent, tmp_path):
    """The same data with the board taken as flat: σ̂0 1.095 against 0.999 with the warp
    free (1080 coordinates, 0.3 px noise); the χ² test of σ̂0 against the noise's σ rejects
    the flat board and accepts the bent one."""
    file = write_project(tmp_path, 0, spacing=SPACING, warp=WARP, name="flat")
    flat = jaxba.adjust_project(jaxba.build_project(jaxba.read_project(file)))
    _, result = bent

    def rejected(adjustment) -> bool:
        redundancy = adjustment.precision.redundancy
        statistic = redundancy * adjustment.sigma0 ** 2
        return statistic > scipy.stats.chi2.ppf(1 - VARIANCE_ALPHA, redundancy)

    assert result.precision.redundancy == flat.precision.redundancy - 2
    assert rejected(flat) and not rejected(result)
    assert flat.sigma0 > 1.05 > result.sigma0
    assert result.boards["board"]["kx"].value == pytest.approx(WARP[0], abs=SIGMAS * 0.2)


def test_project_key_builds_the_warp_block(bent):
    project, result = bent
    assert project.board_ids == ("board",) and project.labels[-2:] == [
        "board board kx", "board board ky"]
    assert np.asarray(project.problem.free.warp).tolist() == [[True, True]]
    (group,) = [g for g in project.problem.groups if isinstance(g, ImagePoints)]
    flat, shape = _points_and_shape()
    np.testing.assert_allclose(np.asarray(group.warp_shape), shape[np.asarray(group.point)])
    board_id = result.boards["board"]
    assert board_id.model == "warp" and board_id["ky"].status == "free"
    assert board_id["ky"].sigma == float(np.asarray(result.precision.std.warp)[0, 1])


def _rewrite(file: pathlib.Path, name: str, edit) -> None:
    path = file.parent / name
    path.write_text(edit(path.read_text()))


def test_a_free_or_bent_points_table_is_refused(tmp_path):
    file = write_project(tmp_path, 0, spacing=SPACING, board_warp=True, name="refused")
    _rewrite(file, "points.txt", lambda text: text.replace(" 0 0 0\n", " - - -\n", 1))
    with pytest.raises(jaxba.ProjectError, match="board_warp: point '1' is not fixed"):
        jaxba.build_project(jaxba.read_project(file))
    _rewrite(file, "points.txt", lambda text: text.replace("- - -", "0 0 0").replace(
        " 0.0 0 0 0\n", " 0.5 0 0 0\n", 1))
    with pytest.raises(jaxba.ProjectError, match="Z are not all equal"):
        jaxba.build_project(jaxba.read_project(file))


def test_schur_refuses_and_auto_takes_dense(bent):
    project, _ = bent
    assert not use_schur(project.problem, "auto")
    with pytest.raises(ValueError, match="solver 'schur' does not adjust a board warp"):
        jaxba.adjust_project(project, solver="schur")
    with pytest.raises(ValueError, match="Schur backend does not adjust a board warp"):
        jaxba.solve(project.problem, jaxba.advanced.Schur())  # the backend named directly
    with pytest.raises(ValueError, match="board warp"):
        pad_problems([project.problem])


def test_jaxba_batch_adjusts_a_warped_project_alone(bent, tmp_path):
    """`jaxba batch`: the warped project beside a flat one, adjusted alone ("single"), its
    results.json with the warp of `jaxba adjust`."""
    warped = write_project(tmp_path / "warped", 0, spacing=SPACING, warp=WARP, board_warp=True,
                           name="warped")
    flat = write_project(tmp_path / "flat", 1, spacing=SPACING, name="flat")
    rows = jaxba.run_batch([warped, flat], tmp_path / "out")
    assert [(row["status"], row["mode"]) for row in rows] == [("ok", "single"), ("ok", "batch")]
    tree = json.loads((tmp_path / "out" / "warped" / "results.json").read_text())
    _, result = bent
    assert tree["board_warp"]["kx"]["value"] == pytest.approx(
        float(np.asarray(result.parameters.warp)[0, 0]), rel=1e-9)
    assert "board_warp" not in json.loads((tmp_path / "out" / "flat" / "results.json").read_text())
