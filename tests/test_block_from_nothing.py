"""A block started from nothing: a synthetic 60-image self-calibration block with no
control and no approximations (every EOP `-`, an empty points table), `datum = "dependent"`,
completed by `jaxba.complete_project` and adjusted, reaches the optimum of the same block
adjusted from the truth: the same σ̂0, redundancy and IOPs, and the same object points up to
the rigid motion that the dependent datum leaves open (the scale comes from the distances)."""

import dataclasses
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


# --- a block with weak points: deferred, then adjusted --------------------------------------

PLANTED_PX = 60.0  # blunders planted into image points: far beyond the noise (0.25 px)
WALL_POINTS = 900  # write_close_range_project's default: the far weak points come after


@pytest.fixture(scope="module")
def weak(tmp_path_factory):
    """The close-range block (16 images, ~3,250 image points: 2-ray points under 2°, 30 px
    of distortion, two sparse images) adjusted from its approximations, and from nothing:
    completed, adjusted without its deferred points, then with them."""
    root = tmp_path_factory.mktemp("weak")
    truth = jaxba.write_close_range_project(root / "truth", seed=0)
    jaxba.write_close_range_project(root / "bare", seed=0, approximations=False)
    reference = jaxba.build_project(jaxba.read_project(truth.project_file))
    spec = jaxba.read_project(root / "bare" / truth.project_file.name)
    completed, completion = jaxba.complete_project(spec)
    project = jaxba.build_project(completed)
    first = jaxba.adjust_project(project)
    again, second, deferral = jaxba.adjust_deferred(completion, project, first)
    return dict(root=root, spec=spec, reference=reference,
                from_truth=jaxba.adjust_project(reference), completion=completion,
                project=project, first=first, again=again, second=second, deferral=deferral)


@pytest.mark.slow  # ~80 s CPU: an initialisation and four adjustments of 3,250 image points
def test_weak_points_are_deferred_then_adjusted_to_the_truths_optimum(weak):
    completion, deferral = weak["completion"], weak["deferral"]
    assert not weak["spec"].complete
    # The far 2-ray points, and only they, wait for the adjusted block; all of them come in.
    assert completion.deferred and all(int(pid) > WALL_POINTS for pid in completion.deferred)
    assert all("meet" in reason for reason in completion.deferred.values())
    assert not set(completion.deferred) & set(completion.spec.points)
    assert deferral.added == completion.deferred and not deferral.left_out
    assert weak["again"].initialisation["added_points"] == list(completion.deferred)

    from_truth, second = weak["from_truth"], weak["second"]
    assert weak["first"].converged and second.converged and from_truth.converged
    assert sorted(weak["again"].point_ids) == sorted(weak["reference"].point_ids)
    assert second.precision.redundancy == from_truth.precision.redundancy
    assert second.sigma0 == pytest.approx(from_truth.sigma0, rel=1e-9)
    np.testing.assert_allclose(np.asarray(second.parameters.cameras["smac"]),
                               np.asarray(from_truth.parameters.cameras["smac"]),
                               rtol=1e-7, atol=1e-9)


@pytest.mark.slow
def test_clean_image_points_are_not_flagged_before_calibration(weak):
    """30 px of distortion at the corner, the camera's 0: no image point is a suspect."""
    initialisation = weak["completion"].initialisation
    assert not np.any(initialisation.blunders) and weak["completion"].suspects == ()
    assert np.nanmax(initialisation.judged) > 5  # misfits far beyond the noise were there


def _plant(folder, rows, rng) -> set:
    """Move image points `rows` (data rows of image_coordinates.txt) by PLANTED_PX pixels
    in random directions; their (image, point) IDs."""
    path = folder / "image_coordinates.txt"
    lines = path.read_text().splitlines(keepends=True)
    data = [k for k, line in enumerate(lines) if not line.startswith("#")]
    planted = set()
    for k in (data[r] for r in rows):
        image, point, x, y = lines[k].split()
        angle = rng.uniform(0.0, 2 * np.pi)
        shift = PLANTED_PX * 0.00369 * np.array([np.cos(angle), np.sin(angle)])  # mm
        lines[k] = f"{image} {point} {float(x) + shift[0]:.8f} {float(y) + shift[1]:.8f}\n"
        planted.add((image, point))
    path.write_text("".join(lines))
    return planted


@pytest.mark.slow  # ~15 s CPU: one initialisation
def test_planted_blunders_are_flagged_or_deferred(weak, tmp_path):
    """Every planted blunder is a suspect, or its point waits for the adjusted block (whose
    residuals judge it); no clean image point is a suspect."""
    shutil.copytree(weak["root"] / "bare", tmp_path / "bare")
    spec = weak["spec"]
    rays = {pid: spec.image_points.point.count(pid) for pid in set(spec.image_points.point)}
    rng = np.random.default_rng(5)
    candidates = [k for k, pid in enumerate(spec.image_points.point) if rays[pid] >= 3]
    planted = _plant(tmp_path / "bare", rng.choice(candidates, 10, replace=False), rng)
    _, completion = jaxba.complete_project(
        jaxba.read_project(tmp_path / "bare" / spec.path.name))
    flagged = {(s.image, s.point) for s in completion.suspects}
    assert flagged <= planted
    assert all(found in flagged or found[1] in completion.deferred for found in planted)
    assert len(flagged) >= 8


@pytest.mark.slow
def test_a_deferred_point_the_adjusted_block_cannot_intersect_is_left_out_and_named(weak):
    """A deferred point with a blunder on one of its 2 rays: its rays do not meet even from
    the adjusted block; left out, named with the image and the miss."""
    from jaxba._adjust._deferred import intersect_deferred

    completion = weak["completion"]
    pending = completion.pending
    table = pending.image_points
    victim = next(iter(completion.deferred))
    row = table.point.index(victim)
    xy = table.xy.copy()
    xy[row] += PLANTED_PX * 0.00369
    broken = dataclasses.replace(completion, pending=dataclasses.replace(
        pending, image_points=dataclasses.replace(table, xy=xy)))
    spec, deferral = intersect_deferred(broken, weak["project"], weak["first"])
    assert list(deferral.left_out) == [victim]
    assert "do not meet" in deferral.left_out[victim]
    assert table.image[row] in deferral.left_out[victim] or "misses" in deferral.left_out[victim]
    assert victim not in spec.points and victim not in spec.image_points.point
    assert set(deferral.added) == set(completion.deferred) - {victim}
    assert any(victim in line for line in deferral.lines())
