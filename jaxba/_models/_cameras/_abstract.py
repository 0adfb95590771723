"""Interfaces of the camera, distortion and refraction models.

A model is a pure function of one observation; parameters are the dataclass fields, named
in `parameter_names`, in the order of the model's parameter vector.
"""

import abc
from typing import ClassVar, Self

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._custom_types import Scalar, Vector2, Vector3


class _Parametrised(eqx.Module):
    """A model whose dynamic fields are exactly its named scalar parameters."""

    parameter_names: ClassVar[tuple[str, ...]]

    @classmethod
    def from_parameters(cls, values: Float[Array, " n"], **constants: float) -> Self:
        """Build the model from its parameter vector (order of `parameter_names`) and its
        constants, if it has any (`AbstractCamera.constant_names`), by name."""
        return cls(*(values[i] for i in range(len(cls.parameter_names))), **constants)

    def parameters(self) -> Float[Array, " n"]:
        """The parameter vector, in the order of `parameter_names`."""
        return jnp.stack([jnp.asarray(getattr(self, name)) for name in self.parameter_names])


class AbstractDistortion(_Parametrised):
    """An additive correction to image coordinates, evaluated at reduced coordinates."""

    @abc.abstractmethod
    def correction(self, reduced: Vector2) -> Vector2:
        """(Δx, Δy) in mm at the reduced image point (x - xp, y - yp), mm."""


class AbstractRefraction(eqx.Module):
    """Atmospheric refraction: a coefficient that depends on the ray's end heights.

    The cameras apply it in image space (k x̄ (1 + r²/c²)), the photogrammetric models at the
    *measured* point: a term no camera-frame ray can carry, hence a coefficient. Refraction
    that bends the ray itself is an `AbstractRayRefraction`.
    """

    @abc.abstractmethod
    def coefficient(self, station: Vector3, point: Vector3) -> Scalar:
        """Refraction coefficient k (dimensionless) for a ray from `point` to `station`."""


class AbstractRayRefraction(_Parametrised):
    """Refraction between the object point and the perspective centre that bends the ray
    (e.g. a flat port: underwater or through-glass imaging), part of a camera: its
    parameters are the camera's (`refracted_camera`), so they are fixed or estimated as
    the camera's are."""

    @abc.abstractmethod
    def ray(self, p_camera: Vector3) -> Vector3:
        """The ray at the perspective centre that, refracted, reaches `p_camera` = M (X - X0)
        (camera frame, object units): a point on it, in the camera frame, in front of the
        camera as `p_camera` is (a central camera sees its direction only); NaN where no
        ray reaches the point."""


class AbstractCamera(_Parametrised):
    """Maps one point in the camera frame to its computed image coordinates.

    `image_units` says what the model computes: "mm" (photogrammetric image frame; pixel
    observations are converted with the camera's pixel grid) or "pixel" (col, row directly).
    `constant_names`: the model's constants, values of a camera that are never unknowns
    (static fields, e.g. the metrology model's r0); `from_parameters` takes them by name,
    and an `ImagePoints` group passes its `constants` there.
    """

    image_units: ClassVar[str]
    constant_names: ClassVar[tuple[str, ...]] = ()

    @abc.abstractmethod
    def image_point(self, p_camera: Vector3, measured: Vector2, refraction_k: Scalar) -> Vector2:
        """Computed image coordinates of `p_camera` = M (X - X0).

        `measured` is the observed image point (correction models of the photogrammetric
        convention are evaluated there); `refraction_k` the atmospheric refraction
        coefficient of this ray (0 when refraction is off).
        """
