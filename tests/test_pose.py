"""Pose models (`jaxba._models._poses`): the camera-frame point, M and X0 against CONVENTIONS.md's
formulas, the conversions by round trip, and the rows' linearised frames against
differentiating the pose itself."""

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import ANGLE_TOL, ROTATION_TOL
from scipy.spatial.transform import Rotation

import jaxba
from jaxba._io._bal import bal_bundle, read_bal
from jaxba._models._poses import (
    POSE_MODELS,
    MatrixPose,
    OpkPose,
    RodriguesPose,
    image_frames,
    image_row_inputs,
)

POINT_RTOL = 1e-14  # camera-frame points of unit-sized scenes, two float64 formulas
DERIVATIVE_RTOL = 1e-13  # row_frame's derivative vs the pose's own, unit-sized values
OPK = np.array([12.0, -3.0, 40.0, 0.1, -0.2, 0.3])  # X0, Y0, Z0, ω, φ, κ
RODRIGUES = np.array([0.3, -1.1, 0.7, 0.4, -0.2, 5.0])  # r, t
TOY = pathlib.Path(__file__).parent / "data" / "bal" / "dubrovnik-3-7-pre.txt"


def test_registry_names_both_poses():
    assert POSE_MODELS == {"opk": OpkPose, "rodrigues": RodriguesPose}
    assert OpkPose.parameter_names == jaxba.IMAGE_PARAMETER_NAMES
    assert RodriguesPose.parameter_names == ("r1", "r2", "r3", "t1", "t2", "t3")


def test_opk_pose_is_the_photogrammetric_pose():
    pose = OpkPose.from_parameters(jnp.asarray(OPK))
    point = jnp.array([10.0, 2.0, 1.0])
    matrix = np.asarray(jaxba.opk_to_matrix(jnp.asarray(OPK[3:])))
    np.testing.assert_allclose(pose.rotation(), matrix, rtol=0, atol=ROTATION_TOL)
    np.testing.assert_array_equal(pose.station(), OPK[:3])
    np.testing.assert_allclose(pose.to_camera(point), matrix @ (np.asarray(point) - OPK[:3]),
                               rtol=POINT_RTOL)
    np.testing.assert_array_equal(pose.parameters(), OPK)


def test_rodrigues_pose_is_bal_pose():
    """P = R(r) X + t (SciPy's rotation vectors), so M = R(r) and X0 = -Rᵀt."""
    pose = RodriguesPose.from_parameters(jnp.asarray(RODRIGUES))
    point = np.array([0.2, -0.5, 0.9])
    matrix = Rotation.from_rotvec(RODRIGUES[:3]).as_matrix()
    expected = matrix @ point + RODRIGUES[3:]
    np.testing.assert_allclose(pose.to_camera(jnp.asarray(point)), expected, rtol=POINT_RTOL)
    np.testing.assert_allclose(pose.rotation(), matrix, rtol=0, atol=ROTATION_TOL)
    station = np.asarray(pose.station())
    np.testing.assert_allclose(station, -matrix.T @ RODRIGUES[3:], rtol=POINT_RTOL)
    np.testing.assert_allclose(matrix @ (point - station), expected, rtol=POINT_RTOL)


@pytest.mark.parametrize("pose, values", [(OpkPose, OPK), (RodriguesPose, RODRIGUES)])
def test_from_rotation_round_trips(pose, values):
    original = pose.from_parameters(jnp.asarray(values))
    again = pose.from_rotation(original.rotation(), original.station())
    np.testing.assert_allclose(again.parameters(), values, rtol=0, atol=ANGLE_TOL * 10)


def test_poses_convert_into_each_other():
    """An OPK pose and the Rodrigues pose of the same M and X0 map points alike."""
    opk = OpkPose.from_parameters(jnp.asarray(OPK))
    rodrigues = RodriguesPose.from_rotation(opk.rotation(), opk.station())
    point = jnp.array([10.0, 2.0, 1.0])
    np.testing.assert_allclose(rodrigues.to_camera(point), opk.to_camera(point), rtol=1e-13)
    back = OpkPose.from_rotation(rodrigues.rotation(), rodrigues.station())
    np.testing.assert_allclose(back.parameters(), OPK, rtol=0, atol=1e-12)


@pytest.mark.parametrize("pose, values", [(OpkPose, OPK), (RodriguesPose, RODRIGUES)])
def test_row_frame_has_the_pose_value_and_derivative(pose, values):
    """A row's frame (from `row_inputs` made image by image as rows make them, moved by δ)
    maps a point as the pose of the moved parameters does, to first order: same value and
    Jacobian by δ at δ = 0."""
    images = jnp.asarray(np.stack([values, values * 0.5]))
    point = jnp.array([0.3, 1.5, -2.0])

    def by_row(delta, row):
        inputs = jax.tree.map(lambda x: x[row], image_row_inputs(pose, images))
        return pose.row_frame(inputs, delta).to_camera(point)

    def by_pose(delta, row):
        return pose.from_parameters(images[row] + delta).to_camera(point)

    @jax.jit  # one program for both rows (op by op: ~100 small programs)
    def values_and_jacobians(row):
        zero = jnp.zeros(6)
        return (by_row(zero, row), by_pose(zero, row), jax.jacrev(by_row)(zero, row),
                jax.jacfwd(by_pose)(zero, row))

    for row in range(2):
        moved_row, moved_pose, jacobian, expected = values_and_jacobians(row)
        np.testing.assert_allclose(moved_row, moved_pose, rtol=POINT_RTOL)
        np.testing.assert_allclose(jacobian, expected, rtol=DERIVATIVE_RTOL,
                                   atol=DERIVATIVE_RTOL * np.abs(expected).max())


def test_frames_are_made_once_per_image():
    images = jnp.asarray(np.stack([OPK, OPK * 0.5]))
    frames = image_frames(OpkPose, images)
    assert isinstance(frames, MatrixPose) and frames.matrix.shape == (2, 3, 3)
    # Rodrigues images too: their matrix maps points as the pose's own cross products do.
    rodrigues = image_frames(RodriguesPose, jnp.asarray(np.stack([RODRIGUES, RODRIGUES * 0.5])))
    assert isinstance(rodrigues, MatrixPose) and rodrigues.matrix.shape == (2, 3, 3)
    point = jnp.array([1.5, -2.0, 7.0])
    for k, values in enumerate([RODRIGUES, RODRIGUES * 0.5]):
        frame = jax.tree.map(lambda x, k=k: x[k], rodrigues)
        expected = RodriguesPose.from_parameters(jnp.asarray(values)).to_camera(point)
        np.testing.assert_allclose(frame.to_camera(point), expected, rtol=1e-14, atol=1e-14)


def test_image_groups_of_one_problem_share_their_pose():
    problem = bal_bundle(read_bal(TOY))
    (group,) = problem.groups
    opk_group = jaxba.ImagePoints("opk", group.model, group.camera, group.image, group.point,
                                  group.measured, group.stddev)
    assert opk_group.pose == "opk"
    with pytest.raises(ValueError, match="different pose models"):
        jaxba.BundleProblem(problem.initial, problem.free, (group, opk_group))
