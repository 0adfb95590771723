"""The report's figures on the adjusted synthetic block (`synthetic_block`): what each draws
checked against the result, computed again here (distortion curve and band, normalised
residuals and normal quantiles, coverage, ellipse axes, scale arrow and bar)."""

import math
import statistics

import numpy as np
import pytest

import jaxba
from jaxba._report._collect import image_residuals
from jaxba._report._plots._base import nice

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")
from matplotlib.collections import EllipseCollection, PolyCollection  # noqa: E402
from matplotlib.quiver import Quiver, QuiverKey  # noqa: E402
from mpl_toolkits.axes_grid1.anchored_artists import AnchoredSizeBar  # noqa: E402

SENSOR_MM = (6000 * 0.00369, 4000 * 0.00369)  # the synthetic camera's format
FIGURES = ["residuals", "normalised_residuals", "coverage", "distortion_C1", "correlation_C1",
           "point_ellipses"]


@pytest.fixture(scope="module")
def block(synthetic_block):
    _, project, result = synthetic_block
    return project, result


def test_figure_set_names(block):
    assert [figure.name for figure in jaxba.figure_set(*block)] == FIGURES


def test_distortion_curves_are_the_profiles_in_micrometres(block):
    project, result = block
    figure = jaxba.plot_distortion(project, result, "C1")
    radial_ax, decentering_ax = (ax for ax in figure.axes if ax.get_xlabel())
    half = np.array(SENSOR_MM) / 2
    corners = [(x, y) for x in (-half[0], half[0]) for y in (-half[1], half[1])]
    from jaxba._statistics._distortion import distortion_profiles

    profiles = distortion_profiles(result, "smac", 0, corners)
    for ax, kind in ((radial_ax, "radial"), (decentering_ax, "decentering")):
        profile = profiles[kind]
        (line,) = [line for line in ax.get_lines() if line.get_label() == kind]
        np.testing.assert_allclose(line.get_xdata(), profile.radius)
        np.testing.assert_allclose(line.get_ydata(), 1000 * profile.value)
        band = next(c for c in ax.collections if isinstance(c, PolyCollection))
        y = band.get_paths()[0].vertices[:, 1]
        assert y.max() == pytest.approx(1000 * np.max(profile.value + profile.std), rel=1e-12)
        assert y.min() == pytest.approx(1000 * np.min(profile.value - profile.std), rel=1e-12)
        assert ax.get_xlim()[1] == pytest.approx(np.hypot(*(half + np.abs(
            np.asarray(result.parameters.cameras["smac"])[0, :2]))), rel=1e-12)
    with pytest.raises(ValueError, match="unknown camera"):
        jaxba.plot_distortion(project, result, "C9")


def test_normalised_residuals_histogram_and_quantiles(block):
    project, result = block
    w = np.concatenate([np.ravel(np.asarray(g)) for g in result.reliability.normalised_residuals])
    w = w[np.isfinite(w)]
    figure = jaxba.plot_normalised_residuals(project, result)
    histogram, quantiles = figure.axes
    heights = np.array([patch.get_height() for patch in histogram.patches])
    widths = np.array([patch.get_width() for patch in histogram.patches])
    assert np.sum(heights * widths) == pytest.approx(1.0, rel=1e-12)  # a density
    assert f"n = {w.size}," in histogram.get_title()
    normal = next(line for line in histogram.get_lines() if line.get_label() == "N(0, 1)")
    x = normal.get_xdata()
    np.testing.assert_allclose(normal.get_ydata(), [statistics.NormalDist().pdf(v) for v in x],
                               rtol=1e-12)
    (points,) = [line for line in quantiles.get_lines() if line.get_marker() == "."]
    expected = [statistics.NormalDist().inv_cdf((i - 0.5) / w.size) for i in range(1, w.size + 1)]
    np.testing.assert_allclose(points.get_xdata(), expected, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(points.get_ydata(), np.sort(w))


def test_coverage_shows_every_observation(block):
    project, result = block
    figure = jaxba.plot_coverage(project, result)
    (ax,) = figure.axes
    xy = np.concatenate([np.asarray(g.measured)[np.asarray(g.mask()).all(axis=1)]
                         for g in result.problem.groups if isinstance(g, jaxba.ImagePoints)])
    shown = ax.collections[0].get_offsets()
    assert sorted(map(tuple, shown)) == sorted(map(tuple, xy))
    counts, _, _ = np.histogram2d(xy[:, 0], xy[:, 1], bins=10,
                                  range=[[-SENSOR_MM[0] / 2, SENSOR_MM[0] / 2],
                                         [-SENSOR_MM[1] / 2, SENSOR_MM[1] / 2]])
    assert f"{np.count_nonzero(counts) / 100:.0%} of the format covered" in ax.get_title()


def test_point_ellipses_are_the_marginal_covariances_scaled(block):
    project, result = block
    figure = jaxba.plot_point_ellipses(project, result)
    covariances = jaxba.point_covariances(result)
    free = np.asarray(project.problem.free.points).any(axis=1)
    scale = float(figure._suptitle.get_text().split(" x ")[1].split()[0])
    largest = 0.0
    for ax, (i, j) in zip(figure.axes, ((0, 1), (0, 2))):
        (ellipses,) = [c for c in ax.collections if isinstance(c, EllipseCollection)]
        a, b, c = (covariances[free][:, i, i], covariances[free][:, i, j],
                   covariances[free][:, j, j])
        root = np.sqrt(((a - c) / 2) ** 2 + b**2)
        major, minor = np.sqrt((a + c) / 2 + root), np.sqrt((a + c) / 2 - root)
        largest = max(largest, major.max())
        np.testing.assert_allclose(ellipses.get_widths(), 2 * scale * major, rtol=1e-9)
        np.testing.assert_allclose(ellipses.get_heights(), 2 * scale * minor, rtol=1e-6)
        # the major axis's direction, mod 180°
        expected = np.degrees(0.5 * np.arctan2(2 * b, a - c))
        turn = (ellipses.get_angles() - expected + 90) % 180 - 90
        np.testing.assert_allclose(turn, 0, atol=1e-6)
        np.testing.assert_allclose(ellipses.get_offsets(),
                                   np.asarray(result.parameters.points)[free][:, [i, j]])
        bar = next(a for a in ax.artists if isinstance(a, AnchoredSizeBar))
        rectangle = bar.size_bar.get_children()[0]
        sigma = float(bar.txt_label.get_text().split("= ")[1])
        assert rectangle.get_width() == pytest.approx(sigma * scale, rel=1e-12)
    extent = np.max(np.ptp(np.asarray(result.parameters.points), axis=0))
    assert scale == nice(0.05 * extent / largest)
    assert sigma == nice(largest)


def test_residual_vectors_clipped_to_the_sensor_with_a_scale_arrow(block):
    project, result = block
    image_id = project.image_ids[0]
    figure = jaxba.plot_image_residuals(project, result, image_id)
    (ax,) = figure.axes
    quiver = next(c for c in ax.collections if isinstance(c, Quiver))
    scale = 1.0 / quiver.scale
    clip = quiver.get_clip_box()  # display coordinates
    corners = ax.transData.transform([[-SENSOR_MM[0] / 2, -SENSOR_MM[1] / 2],
                                      [SENSOR_MM[0] / 2, SENSOR_MM[1] / 2]])
    np.testing.assert_allclose([[clip.x0, clip.y0], [clip.x1, clip.y1]], corners, rtol=1e-9)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert x0 < -SENSOR_MM[0] / 2 and x1 > SENSOR_MM[0] / 2
    assert y0 < -SENSOR_MM[1] / 2 and y1 > SENSOR_MM[1] / 2
    key = next(a for a in ax.get_children() if isinstance(a, QuiverKey))
    residuals = image_residuals(project, result)
    chosen = residuals.image_ids == image_id
    rms = math.sqrt(np.mean(np.sum(residuals.v[chosen] ** 2, axis=1)))
    assert scale == nice(0.06 * SENSOR_MM[0] / rms)
    assert key.Q is quiver and key.U == nice(rms)
    assert key.text.get_text() == f"{key.U * 1000:g} µm"
    figure.draw_without_rendering()
    arrow = key.vector.get_transform().transform(key.vector.get_paths()[0].vertices)
    drawn = ax.transData.transform([[0.0, 0.0], [key.U * scale, 0.0]])  # U mm, x scale
    assert np.ptp(arrow[:, 0]) == pytest.approx(drawn[1, 0] - drawn[0, 0], rel=1e-9)
