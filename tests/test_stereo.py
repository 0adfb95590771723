"""A stereo rig calibrated from OpenCV's sample pairs (tests/data/opencv_stereo) against OpenCV's
`stereoCalibrate` run here on the same corners with the same model (`opencv`, all intrinsics
and the relative pose free), and against the same images adjusted without the rig."""

import numpy as np
import pytest
from stereo_scene import FLIP, PAIRS, image_row, opencv_stereo, write_project

import jaxba
from jaxba._models._rotation_numpy import opk_to_matrix
from jaxba._statistics._rigs import baseline

pytest.importorskip("cv2")

# Both minimise the same sum of squares over the same unknowns; OpenCV iterates to 1e-15
# (`STRICT`): the solutions agree to a small fraction of σ.
OPENCV_SIGMA_FRACTION = 0.01
INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@pytest.fixture(scope="module")
def scene():
    return opencv_stereo()


@pytest.fixture(scope="module")
def rig(scene, tmp_path_factory):
    path = write_project(tmp_path_factory.mktemp("rig"), scene)
    project = jaxba.build_project(jaxba.read_project(path))
    return project, jaxba.adjust_project(project)


def test_rig_equals_opencv_stereo_calibrate(scene, rig):
    """Baseline, relative rotation and both cameras' intrinsics as `stereoCalibrate`'s."""
    project, result = rig
    assert result.converged
    k1, d1, k2, d2, rotation, translation = scene.stereo
    right = result.mounts["stereo/right"]
    centre = np.array([right[n].value for n in ("X0", "Y0", "Z0")])
    sigma = np.array([right[n].sigma for n in ("X0", "Y0", "Z0")])
    # OpenCV: p_right = R p_left + T in its camera frames, jaxba's are flipped (FLIP).
    expected = -FLIP @ rotation.T @ np.ravel(translation)
    np.testing.assert_array_less(np.abs(centre - expected), OPENCV_SIGMA_FRACTION * sigma)
    length, length_sigma = baseline(result.parameters, result.precision, 1)
    assert abs(length - np.linalg.norm(translation)) < OPENCV_SIGMA_FRACTION * length_sigma
    angles = np.array([right[n].value for n in ("omega", "phi", "kappa")])
    turned = opk_to_matrix(angles) - FLIP @ rotation @ FLIP
    angle_sigma = min(right[n].sigma for n in ("omega", "phi", "kappa"))
    assert np.max(np.abs(turned)) < OPENCV_SIGMA_FRACTION * angle_sigma
    for camera, matrix, dist in (("left", k1, d1), ("right", k2, d2)):
        opencv = dict(zip(INTRINSICS, [matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2],
                                       *np.ravel(dist)[:5]]))
        estimates = result.cameras[camera]
        for name in INTRINSICS:
            difference = abs(estimates[name].value - opencv[name])
            assert difference < OPENCV_SIGMA_FRACTION * estimates[name].sigma, (camera, name)


def test_released_rig_implies_the_same_relative_pose(scene, rig, tmp_path):
    """Without the rig every image has its own pose: the relative poses of the 13 pairs
    scatter about the rig's, their mean within 3 of its σ (the pairs' spread / sqrt(13)).
    The cameras are those the rig calibrated, fixed: cameras calibrated apart differ (the
    right fx by 0.5 %), and with them every image's distance from the board."""
    _, result = rig
    intrinsics = {side: [result.cameras[side][n].value for n in INTRINSICS]
                  for side in ("left", "right")}
    path = write_project(tmp_path, scene, rig=False, intrinsics=intrinsics)
    released = jaxba.adjust_project(jaxba.build_project(jaxba.read_project(path)))
    assert released.converged
    centres, angles = [], []
    for pair in PAIRS:
        left, right = (released.images[f"{side}{pair:02d}"] for side in ("left", "right"))
        rows = [np.array([pose[n].value for n in pose]) for pose in (left, right)]
        m_left = opk_to_matrix(rows[0][3:])
        centres.append(m_left @ (rows[1][:3] - rows[0][:3]))
        relative = opk_to_matrix(rows[1][3:]) @ m_left.T
        angles.append([relative[1, 2], -relative[0, 2], relative[0, 1]])  # small angles
    mount = result.parameters.mounts[1]
    m_mount = opk_to_matrix(mount[3:])
    rig_values = np.concatenate([mount[:3], [m_mount[1, 2], -m_mount[0, 2], m_mount[0, 1]]])
    pairs = np.column_stack([centres, angles])
    bound = 3 * np.std(pairs, axis=0, ddof=1) / np.sqrt(len(PAIRS))
    np.testing.assert_array_less(np.abs(pairs.mean(axis=0) - rig_values), bound)


def test_image_row_round_trip(scene):
    """`image_row` (the test's own conversion) maps OpenCV's pose to jaxba's: the board's
    corners project through the jaxba camera to where OpenCV's `projectPoints` puts them."""
    import cv2

    matrix, dist, rvecs, tvecs = scene.single["left"]
    row = np.array(image_row(rvecs[0], tvecs[0]))
    m = opk_to_matrix(np.radians(row[3:]))
    p = (FLIP @ m @ (scene.board - row[:3]).T).T
    expected = cv2.projectPoints(scene.board, rvecs[0], tvecs[0], matrix, np.zeros(5))[0]
    ideal = p[:, :2] / p[:, 2:] @ np.diag([matrix[0, 0], matrix[1, 1]]) + matrix[:2, 2]
    np.testing.assert_allclose(ideal, expected.reshape(-1, 2), atol=1e-9)


def test_results_json_reports_the_rig(rig, tmp_path):
    """results.json: "rigs" with the right camera's relative pose (degrees) and baseline,
    their σ; "frames" one per pair; "images" every image, the right ones composed; the .out
    has the rig section."""
    import json

    project, result = rig
    jaxba.write_reports(project, result, tmp_path)
    tree = json.loads((tmp_path / "results.json").read_text())
    right = tree["rigs"]["stereo"]["right"]
    length, sigma = baseline(result.parameters, result.precision, 1)
    assert right["baseline"] == {"value": length, "std": sigma}
    assert right["phi"]["value"] == pytest.approx(np.degrees(result.parameters.mounts[1, 4]))
    assert right["X0"]["status"] == "free" and right["X0"]["std"] > 0
    assert list(tree["frames"]) == [f"pair{k:02d}" for k in PAIRS]
    assert len(tree["images"]) == 2 * len(PAIRS)
    # A left image is its frame; a right image is the frame followed by the rig's pose.
    for name, entry in tree["frames"]["pair03"].items():  # composed with the identity
        assert tree["images"]["left03"][name]["value"] == pytest.approx(entry["value"], abs=1e-12)
        assert tree["images"]["left03"][name]["std"] == pytest.approx(entry["std"], rel=1e-9)
    m = opk_to_matrix(result.parameters.images[2, 3:])
    centre = result.parameters.images[2, :3] + m.T @ result.parameters.mounts[1, :3]
    assert [tree["images"]["right03"][n]["value"] for n in ("X0", "Y0", "Z0")] == (
        pytest.approx(centre.tolist(), abs=1e-12))
    assert tree["correlations"]["stereo/right"]["parameters"] == [
        "X0", "Y0", "Z0", "omega", "phi", "kappa"]
    out = (tmp_path / "stereo.out").read_text()
    assert "Baselines" in out and "stereo/right" in out
    from jaxba._report._plots._set import figure_set

    figures = {figure.name: b"" for figure in figure_set(project, result)}  # not drawn
    page = jaxba.html_report(project, result, figures=figures)
    assert '<section id="rigs">' in page and "pair13" in page


def test_exported_stereo_yaml_equals_opencv_stereo_calibrate(scene, rig, tmp_path):
    """The adjusted rig through `jaxba export --format opencv`: OpenCV's stereo YAML whose R
    and T are those of `stereoCalibrate` on the same corners (to a small fraction of σ), and
    whose K1, D1, K2, D2 are the adjusted cameras'."""
    cv2 = pytest.importorskip("cv2")
    from jaxba._cli._main import main

    project, result = rig
    jaxba.write_reports(project, result, tmp_path / "out")
    assert main(["export", str(tmp_path / "out"), "--format", "opencv"]) == 0
    (path,) = (tmp_path / "out" / "export" / "opencv").glob("stereo_*right*.yml")
    stored = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    rotation, translation = (stored.getNode(n).mat() for n in ("R", "T"))
    _, _, _, _, expected_rotation, expected_translation = scene.stereo
    right = result.mounts["stereo/right"]
    centre_sigma = max(right[n].sigma for n in ("X0", "Y0", "Z0"))
    angle_sigma = min(right[n].sigma for n in ("omega", "phi", "kappa"))
    np.testing.assert_allclose(translation.ravel(), np.ravel(expected_translation),
                               atol=OPENCV_SIGMA_FRACTION * centre_sigma)
    np.testing.assert_allclose(rotation, expected_rotation,
                               atol=OPENCV_SIGMA_FRACTION * angle_sigma)
    k2 = stored.getNode("K2").mat()
    assert k2[0, 0] == pytest.approx(result.cameras["right"]["fx"].value, rel=1e-12)
    assert stored.getNode("D1").mat().ravel()[0] == pytest.approx(
        result.cameras["left"]["k1"].value, rel=1e-12)


def test_projection_uncertainty_of_a_rig(rig):
    """Both cameras of the rig are mapped in both frames. In the default frame the right
    camera's view of the world moves with its frame's pose and its pose in the rig: the
    motion T that `_frame_map` gives linearly equals T fitted by nonlinear least squares to
    the camera-frame points of a perturbed solution (frames, mount and points moved)."""
    import jax
    from scipy.optimize import least_squares

    from jaxba._problem._parameters import flatten, unflatten
    from jaxba._report._uncertainty import camera_uncertainties
    from jaxba._statistics._projection import (
        _camera,
        _frame_map,
        _moved,
        camera_frame,
        camera_ref,
        camera_rows,
    )

    project, result = rig
    for frame in ("object", "camera"):
        maps, notes = camera_uncertainties(project, result, frame=frame)
        assert [m.camera_id for m in maps] == ["left", "right"] and not notes
        assert all(np.all(np.isfinite(m.uncertainty.sigma_worst)) for m in maps)
    params, ref = result.parameters, camera_ref(result, "right")
    flat = flatten(params)
    mapping, cols = _frame_map(result, ref, unflatten(params, np.arange(flat.size)))
    iop = np.asarray(params.cameras[ref.model][ref.row])
    delta = np.zeros(flat.size)
    delta[cols[iop.size:]] = 1e-6 * np.random.default_rng(0).standard_normal(cols.size - iop.size)
    linear = mapping[iop.size:] @ delta[cols]
    moved = unflatten(params, flat + delta)
    camera = _camera(ref.model, ref.constants, jax.device_put(iop))
    (k,) = ref.groups
    group = result.problem.groups[k]
    rows = np.flatnonzero(np.asarray(group.camera) == ref.row)
    measured, sigma = np.asarray(group.measured)[rows], np.asarray(group.stddev)[rows]
    assert group.mount is not None and np.all(np.asarray(group.mount)[rows] == 1)

    def in_camera(parameters):
        points = np.asarray(parameters.points)[np.asarray(group.point)[rows]]
        return jax.vmap(lambda e, x: camera_frame(group.pose, e).to_camera(x))(
            camera_rows(parameters, group, rows), points)

    before, after = in_camera(params), in_camera(moved)
    image = jax.jit(jax.vmap(lambda p, m: camera.image_point(p, m, 0.0)))
    target = np.asarray(image(after, measured))

    def misfit(motion):
        turned = jax.vmap(lambda p: _moved(p, motion, True))(before)
        return ((np.asarray(image(turned, measured)) - target) / sigma).ravel()

    fitted = least_squares(misfit, np.zeros(6), xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    assert np.max(np.abs(linear)) > 1e-8  # the perturbation moves the camera's view
    np.testing.assert_allclose(fitted, linear, rtol=0, atol=1e-3 * np.max(np.abs(linear)))
