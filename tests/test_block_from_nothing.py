"""A block started from nothing: a synthetic 60-image self-calibration block with no
control and no approximations (every EOP `-`, an empty points table), `datum = "dependent"`,
completed by `jaxba.complete_project` and adjusted, reaches the optimum of the same block
adjusted from the truth: the same σ̂0, redundancy and IOPs, and the same object points up to
the rigid motion that the dependent datum leaves open (the scale comes from the distances)."""

import shutil

import numpy as np
import pytest

import jaxba

N_IMAGES, N_TARGETS = 60, 20  # 60 convergent images of 20 targets: ~20 image points each


def _dependent(project_file):
    text = project_file.read_text()
    project_file.write_text(text.replace("[adjustment]", '[adjustment]\ndatum = "dependent"'))


def _strip_approximations(folder):
    """Every EOP `-` and no row in the points table (all points are tie points)."""
    images = folder / "orientation.txt"
    images.write_text("".join(
        line if line.startswith("#") else " ".join(line.split()[:2] + ["-"] * 6) + "\n"
        for line in images.read_text().splitlines(keepends=True)))
    points = folder / "ground_points.txt"
    points.write_text(points.read_text().splitlines(keepends=True)[0])  # the header only


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("nothing")
    truth = jaxba.write_synthetic_project(
        root / "truth", seed=1, n_images=N_IMAGES, n_targets=N_TARGETS, datum="none",
        approx_error=(0.0, 0.0, 0.0))  # approximations = the truth
    _dependent(truth.project_file)
    shutil.copytree(root / "truth", root / "bare")
    _strip_approximations(root / "bare")

    reference = jaxba.build_project(jaxba.read_project(truth.project_file))
    spec = jaxba.read_project(root / "bare" / truth.project_file.name)
    completed, completion = jaxba.complete_project(spec)
    project = jaxba.build_project(completed)
    return (spec, completion, reference, jaxba.adjust_project(reference), project,
            jaxba.adjust_project(project))


@pytest.mark.slow  # ~19 s CPU: 60 images initialised (resections, robust intersections)
def test_a_60_image_block_from_nothing_reaches_the_truths_optimum(block):
    spec, completion, reference, from_truth, project, from_nothing = block
    assert not spec.complete and len(spec.images) == N_IMAGES
    assert len(completion.computed_images) == N_IMAGES
    assert len(completion.computed_points) == N_TARGETS
    assert project.datum["kind"] == "dependent" and project.datum["scale"] == "distances"

    assert from_truth.converged and from_nothing.converged
    assert from_nothing.precision.redundancy == from_truth.precision.redundancy
    assert from_nothing.sigma0 == pytest.approx(from_truth.sigma0, rel=1e-9)
    np.testing.assert_allclose(np.asarray(from_nothing.parameters.cameras["smac"]),
                               np.asarray(from_truth.parameters.cameras["smac"]),
                               rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(np.asarray(from_nothing.precision.std.cameras["smac"]),
                               np.asarray(from_truth.precision.std.cameras["smac"]), rtol=1e-6)

    # The points, by ID: a rigid motion apart (both datums fix a first image and take the
    # scale from the same distances; the computed first image is not the true one).
    order = [project.point_ids.index(pid) for pid in reference.point_ids]
    points = np.asarray(from_nothing.parameters.points)[order]
    similarity = jaxba.absolute_orientation(points, np.asarray(from_truth.parameters.points))
    assert similarity.scale == pytest.approx(1.0, abs=1e-9)
    assert np.max(np.abs(similarity.residuals)) < 1e-8  # m
