"""jaxba's photogrammetric pose: perspective centre X0 and angles omega, phi, kappa."""

from typing import Self

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._custom_types import Matrix3, Scalar, Vector3
from .._rotation import matrix_to_opk, opk_to_matrix
from ._abstract import AbstractPose, MatrixPose


class OpkPose(AbstractPose):
    """Images row (X0, Y0, Z0, omega, phi, kappa): object units and radians, with
    M = R3(kappa) R2(phi) R1(omega) (docs/conventions.md) and p_camera = M (X - X0).

    Rows use the matrix M made once per image (`frame`, a `MatrixPose`) and, to
    differentiate, its derivative by the angles, M + (dM/d(ω, φ, κ)) δ: three angles' sines
    and cosines per row cost more than gathering the entries.
    """

    X0: Scalar
    Y0: Scalar
    Z0: Scalar
    omega: Scalar
    phi: Scalar
    kappa: Scalar
    parameter_names = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
    angle_names = ("omega", "phi", "kappa")  # in radians

    def to_camera(self, point: Vector3) -> Vector3:
        return self.frame().to_camera(point)

    def rotation(self) -> Matrix3:
        return opk_to_matrix(jnp.stack([self.omega, self.phi, self.kappa]))

    def station(self) -> Vector3:
        return jnp.stack([self.X0, self.Y0, self.Z0])

    @classmethod
    def from_rotation(cls, rotation: Matrix3, station: Vector3) -> Self:
        return cls.from_parameters(jnp.concatenate([station, matrix_to_opk(rotation)]))

    def frame(self) -> MatrixPose:
        return MatrixPose(self.rotation(), self.station())

    @classmethod
    def row_inputs(cls, images: Float[Array, "n_images 6"]) -> tuple[Array, Array, Array]:
        """X0 (n_images, 3), M (n_images, 3, 3) and dM/d(ω, φ, κ) (n_images, 3, 3, 3)."""
        angles = images[:, 3:]
        return (images[:, :3], jax.vmap(opk_to_matrix)(angles),
                jax.vmap(jax.jacfwd(opk_to_matrix))(angles))

    @classmethod
    def row_frame(cls, inputs: tuple[Array, Array, Array], delta: Float[Array, "6"]) -> MatrixPose:
        station, matrix, derivative = inputs
        moved = matrix + sum(derivative[:, :, k] * delta[3 + k] for k in range(3))
        return MatrixPose(moved, station + delta[:3])
