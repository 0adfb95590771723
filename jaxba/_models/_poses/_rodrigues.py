"""BAL's pose: a Rodrigues (axis-angle) rotation and a translation, P = R(r) X + t."""

from typing import Self

import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._custom_types import Matrix3, Scalar, Vector3
from .._rotation import matrix_to_rodrigues, rodrigues_to_matrix
from ._abstract import AbstractPose, MatrixPose


class RodriguesPose(AbstractPose):
    """Images row (r1, r2, r3, t1, t2, t3): the camera-frame point is P = R(r) X + t
    (Snavely's Bundler / BAL, Ceres' `SnavelyReprojectionError`), so M = R(r) and
    X0 = -Rᵀ t; r in radians, t in object units.

    Rows map points with the image's matrix (`frame`, made once per image: the sine and
    cosine per image, not per row; BAL's residuals 4.3 -> 1.2 ms on Dubrovnik-16) and
    differentiate the pose from its parameters (`row_inputs`): `rotate_point`'s cross
    products cost less per row than gathering a matrix and chaining its derivative.
    """

    r1: Scalar
    r2: Scalar
    r3: Scalar
    t1: Scalar
    t2: Scalar
    t3: Scalar
    parameter_names = ("r1", "r2", "r3", "t1", "t2", "t3")
    angle_names = ("r1", "r2", "r3")  # the rotation vector, radians

    def to_camera(self, point: Vector3) -> Vector3:
        return rotate_point(self._r(), point) + self._t()

    def rotation(self) -> Matrix3:
        return rodrigues_to_matrix(self._r())

    def station(self) -> Vector3:
        return -self.rotation().T @ self._t()

    @classmethod
    def from_rotation(cls, rotation: Matrix3, station: Vector3) -> Self:
        return cls.from_parameters(
            jnp.concatenate([matrix_to_rodrigues(rotation), -rotation @ station]))

    def frame(self) -> MatrixPose:
        return MatrixPose(self.rotation(), self.station())

    @classmethod
    def row_inputs(cls, images: Float[Array, "n_images 6"]) -> Float[Array, "n_images 6"]:
        return images

    @classmethod
    def row_frame(cls, inputs: Float[Array, "6"], delta: Float[Array, "6"]) -> Self:
        return cls.from_parameters(inputs + delta)

    def _r(self) -> Vector3:
        return jnp.stack([self.r1, self.r2, self.r3])

    def _t(self) -> Vector3:
        return jnp.stack([self.t1, self.t2, self.t3])


def rotate_point(r: Vector3, x: Vector3) -> Vector3:
    """R(r) x for the Rodrigues (axis-angle) vector r, written out with cross products.

    R x = x + (sin θ / θ) r × x + ((1 - cos θ) / θ²) r × (r × x), θ = |r|, with the
    Taylor expansions 1 - θ²/6 and 1/2 - θ²/24 near θ = 0 (values and derivatives stay
    exact). Same rotation as `jaxba.rodrigues_to_matrix(r) @ x` and Ceres'
    `AngleAxisRotatePoint`; written elementwise because vmapped 3x3 matrix products
    are slow on CPU (this makes the solver's linearisation ~3x faster on BAL).
    """
    theta2 = r[0] ** 2 + r[1] ** 2 + r[2] ** 2
    small = theta2 < 1e-24
    safe_theta2 = jnp.where(small, 1.0, theta2)
    theta = jnp.sqrt(safe_theta2)
    sin_term = jnp.where(small, 1.0 - theta2 / 6.0, jnp.sin(theta) / theta)
    cos_term = jnp.where(small, 0.5 - theta2 / 24.0, (1.0 - jnp.cos(theta)) / safe_theta2)
    cross = _cross(r, x)
    double_cross = _cross(r, cross)
    return jnp.stack([x[i] + sin_term * cross[i] + cos_term * double_cross[i] for i in range(3)])


def _cross(a, b) -> tuple:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
