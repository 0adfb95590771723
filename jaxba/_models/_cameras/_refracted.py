"""A camera behind a ray refraction model (e.g. "smac+flat_port"): the camera model projects
the refracted ray, so any camera model works behind any ray refraction."""

import functools
from typing import ClassVar, Self

import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._custom_types import Scalar, Vector2, Vector3
from ._abstract import AbstractCamera, AbstractRayRefraction
from ._user import CameraModelError


class RefractedCamera(AbstractCamera):
    """`lens` (a camera model) seeing through `refraction`: image_point(P) =
    lens.image_point(refraction.ray(P)). Its parameters are the lens's, then the
    refraction's; the classes of a pair are made by `refracted_camera`."""

    lens: AbstractCamera
    refraction: AbstractRayRefraction
    lens_model: ClassVar[type[AbstractCamera]]
    refraction_model: ClassVar[type[AbstractRayRefraction]]

    @classmethod
    def from_parameters(cls, values: Float[Array, " n"], **constants: float) -> Self:
        n_lens = len(cls.lens_model.parameter_names)
        return cls(cls.lens_model.from_parameters(values[:n_lens], **constants),
                   cls.refraction_model.from_parameters(values[n_lens:]))

    def parameters(self) -> Float[Array, " n"]:
        return jnp.concatenate([self.lens.parameters(), self.refraction.parameters()])

    def image_point(self, p_camera: Vector3, measured: Vector2, refraction_k: Scalar) -> Vector2:
        return self.lens.image_point(self.refraction.ray(p_camera), measured, refraction_k)


@functools.cache
def refracted_camera(
    lens: type[AbstractCamera], refraction: type[AbstractRayRefraction], name: str
) -> type[RefractedCamera]:
    """The camera model `name` ("<lens>+<refraction>"): `lens` behind
    `refraction`, one class per pair. Raises `CameraModelError` when their parameter names clash."""
    clash = sorted(set(lens.parameter_names) & set(refraction.parameter_names))
    if clash:
        raise CameraModelError(f"camera model {name!r}: the camera's and the refraction's"
                               f" parameters share the names {', '.join(clash)}")
    attributes = {
        "parameter_names": lens.parameter_names + refraction.parameter_names,
        "image_units": lens.image_units,
        "constant_names": lens.constant_names,
        "lens_model": lens,
        "refraction_model": refraction,
        "__doc__": f"Camera model {name!r}: {lens.__name__} behind {refraction.__name__}.",
    }
    class_name = f"{lens.__name__}Behind{refraction.__name__}"
    return type(RefractedCamera)(class_name, (RefractedCamera,), attributes)
