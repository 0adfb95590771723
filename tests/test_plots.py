"""Tests of the plots on hand-made adjustment results (no solve): the figures build, with one
Axes per image and one arrow per image observation, outliers drawn apart."""

import dataclasses
import pathlib

import numpy as np
import pytest

import jaxba
from jaxba._problem._bundle import free_indices
from jaxba._statistics._covariance import Precision
from jaxba.advanced import flatten, unflatten

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")
from matplotlib.quiver import Quiver  # noqa: E402

CONFIGS = pathlib.Path(__file__).resolve().parents[1] / "configs"
CRITICAL = 3.29  # critical |w| of the hand-made reliability
SMAC_FREE = ["xp", "yp", "c", "K1", "K2", "K3", "P1", "P2"]  # configs/lab/cameras.toml


def _fake_result(project, *, seed: int = 0) -> jaxba.Adjustment:
    """Approximations as the solution, random residuals, covariance and w; the image point
    of row 3 of the first group removed by 'data snooping', the w of row 0 above critical."""
    problem = jaxba.remove_observation(project.problem, 0, 3, 0)
    rng = np.random.default_rng(seed)
    masks = [np.asarray(group.mask()) for group in problem.groups]
    residuals = tuple(rng.normal(0.0, 1e-3, m.shape) * m for m in masks)
    w = [np.where(m, rng.normal(0.0, 1.0, m.shape).clip(-3, 3), np.nan) for m in masks]
    w[0][0, 0] = 5.0
    r = tuple(np.where(m, 0.5, np.nan) for m in masks)
    n, u = problem.n_observations(), problem.n_unknowns()
    factor = rng.normal(0.0, 1e-4, (u, u + 5))
    std = unflatten(problem.free, np.zeros(flatten(problem.free).size))
    return jaxba.Adjustment(
        problem=problem, parameters=problem.initial,
        precision=Precision(1.0, n - u, n, u, free_indices(problem), factor @ factor.T, std),
        residuals=residuals, iterations=[jaxba.Iteration(0, 1.0, 1.0)], converged=True,
        message="converged", steps=1,
        reliability=jaxba.Reliability(r, tuple(w), r, 0.001, CRITICAL),
        rejections=(jaxba.Rejection(problem.groups[0].name, 3, 0, 9.0),),
    )


@pytest.fixture(scope="module")
def lab():
    project = jaxba.build_project(jaxba.read_project(CONFIGS / "lab" / "lab.toml"))
    return project, _fake_result(project)


def _arrows(ax) -> tuple[int, int]:
    """(blue, red) arrow counts of an Axes."""
    counts = {"blue": 0, "red": 0}
    for quiver in (c for c in ax.collections if isinstance(c, Quiver)):
        red = quiver.get_facecolor()[0][0] > 0.5
        counts["red" if red else "blue"] += quiver.N
    return counts["blue"], counts["red"]


def _observations_per_image(project) -> dict[str, int]:
    counts = {}
    for m in project.spec.image_points:
        counts[m.image] = counts.get(m.image, 0) + 1
    return counts


def test_all_images_one_axes_and_one_arrow_per_observation(lab, tmp_path):
    project, result = lab
    figure = jaxba.plot_image_residuals(project, result)
    assert len(figure.axes) == len(project.image_ids)
    counts = _observations_per_image(project)
    group = result.problem.groups[0]
    outlier_images = {project.image_ids[int(group.image[k])] for k in (0, 3)}
    red_total = 0
    for ax in figure.axes:
        image_id = ax.get_title().split()[0]
        blue, red = _arrows(ax)
        assert blue + red == counts[image_id]
        assert (red > 0) == (image_id in outlier_images)
        red_total += red
    assert red_total == 2  # the removed point and the one with |w| > critical
    figure.savefig(tmp_path / "residuals.png", dpi=40)
    assert (tmp_path / "residuals.png").stat().st_size > 0


def test_one_image_and_scale(lab):
    project, result = lab
    image_id = project.image_ids[4]
    figure = jaxba.plot_image_residuals(project, result, image_id, scale=2000.0)
    (ax,) = figure.axes
    assert sum(_arrows(ax)) == _observations_per_image(project)[image_id]
    quiver = next(c for c in ax.collections if isinstance(c, Quiver))
    assert quiver.scale == pytest.approx(1 / 2000.0)
    assert "x 2000" in figure._suptitle.get_text()
    x0, x1 = ax.get_xlim()
    assert x0 < -0.00369 * 3000 and x1 > 0.00369 * 3000  # the sensor outline is in view, mm
    with pytest.raises(ValueError, match="unknown image"):
        jaxba.plot_image_residuals(project, result, "nowhere")


def test_pixel_camera_rows_down():
    project = jaxba.build_project(jaxba.read_project(CONFIGS / "zhang" / "zhang.toml"))
    result = dataclasses.replace(_fake_result(project), rejections=())
    figure = jaxba.plot_image_residuals(project, result, project.image_ids[0])
    (ax,) = figure.axes
    y0, y1 = ax.get_ylim()
    assert y0 > y1  # row down
    assert "pixels" in figure._suptitle.get_text()
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("col (px)", "row (px)")


def test_every_axis_carries_its_unit(lab):
    """The lab's mm camera: residual vectors and coverage in x, y (mm); the point ellipses
    in object units."""
    project, result = lab
    for figure in (jaxba.plot_image_residuals(project, result),
                   jaxba.plot_coverage(project, result)):
        assert {(ax.get_xlabel(), ax.get_ylabel()) for ax in figure.axes} == {("x (mm)", "y (mm)")}
    ellipses = jaxba.plot_point_ellipses(project, result)
    assert [(ax.get_xlabel(), ax.get_ylabel()) for ax in ellipses.axes] == [
        ("X (object units)", "Y (object units)"), ("X (object units)", "Z (object units)")]


def test_correlation_heat_map(lab):
    project, result = lab
    figure = jaxba.plot_correlation(result, project, "C1")
    assert len(figure.axes) == 2  # the matrix and its colour bar
    ax = figure.axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == SMAC_FREE
    assert len(ax.texts) == len(SMAC_FREE) ** 2
    names, matrix = jaxba.camera_correlation(result, "smac", 0)
    np.testing.assert_allclose(ax.images[0].get_array(), matrix)
    assert ax.texts[1].get_text() == f"{matrix[0, 1]:.2f}"
    with pytest.raises(ValueError, match="unknown camera"):
        jaxba.plot_correlation(result, project, "C9")


def test_distortion_of_a_pixel_camera_draws_its_estimated_kinds_only():
    """Zhang's OpenCV camera estimates k1, k2 and no decentering: one panel, in pixels, out to
    the 640 x 480 sensor's corner farthest from (cx, cy) = (320, 240)."""
    project = jaxba.build_project(jaxba.read_project(CONFIGS / "zhang" / "zhang.toml"))
    figure = jaxba.plot_distortion(project, _fake_result(project))
    (ax,) = [ax for ax in figure.axes if ax.get_xlabel()]
    assert ax.get_xlabel().endswith("(px)") and ax.get_ylabel() == "radial (px)"
    assert "k1, k2 estimated" in ax.get_title()
    assert ax.get_xlim()[1] == pytest.approx(np.hypot(320.5, 240.5), rel=1e-12)
    assert jaxba.figure_set(project, _fake_result(project))[3].name == "distortion_C1"
