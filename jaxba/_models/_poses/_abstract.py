"""The interface of pose models, and how the rows of an image group evaluate and
differentiate them.

A pose maps object points into an image's camera frame, p_camera = M (X - X0), with M = R_m^c
of docs/conventions.md (object frame -> camera frame) and X0 the perspective centre. Its parameters
are the dataclass fields, named in `parameter_names`: the columns of `Parameters.images`.
"""

import abc
from collections.abc import Callable
from typing import ClassVar, Self

import equinox as eqx
import jax
from jaxtyping import Array, Float, PyTree

from ..._custom_types import Matrix3, Vector3
from .._cameras._abstract import _Parametrised


class MatrixPose(eqx.Module):
    """A pose given by its rotation matrix M (3, 3) and perspective centre X0 (3,): the form
    in which rows map points when M is cheaper gathered than recomputed (`OpkPose.frame`)."""

    matrix: Matrix3
    centre: Vector3

    def to_camera(self, point: Vector3) -> Vector3:
        """p_camera = M (X - X0)."""
        return self.matrix @ (point - self.centre)

    def rotation(self) -> Matrix3:
        return self.matrix

    def station(self) -> Vector3:
        return self.centre


class AbstractPose(_Parametrised):
    """The exterior orientation of one image, parameterised by six scalars.

    - `to_camera(X)`: the camera-frame point p_camera = M (X - X0) (camera units of the
      object frame), what the camera models project;
    - `rotation()`, `station()`: M and X0 (the datum's similarity transform, reports,
      refraction);
    - `from_rotation(M, X0)`: the inverse conversion;
    - `frame()`: the form rows evaluate (`to_camera`, `station`), made once per image;
    - `row_inputs(images)`, `row_frame(inputs, delta)`: how rows differentiate the pose:
      per image what rows need (made once), and per row the frame of the image's
      parameters moved by `delta` (6,), exact in value and first derivative at delta = 0.
      A pose whose own formula is cheap per row passes its parameters (Rodrigues); one
      whose formula is dear passes its frame and its derivative (OPK's sines and cosines).

    `parameter_names` name the six parameters; `angle_names` those among them in radians.
    """

    angle_names: ClassVar[tuple[str, ...]] = ()

    @abc.abstractmethod
    def to_camera(self, point: Vector3) -> Vector3:
        """p_camera = M (X - X0) of the object point `point`."""

    @abc.abstractmethod
    def rotation(self) -> Matrix3:
        """M = R_m^c, rotating object-frame vectors into the camera frame."""

    @abc.abstractmethod
    def station(self) -> Vector3:
        """X0, the perspective centre in the object frame."""

    @classmethod
    @abc.abstractmethod
    def from_rotation(cls, rotation: Matrix3, station: Vector3) -> Self:
        """The pose with M = `rotation` and X0 = `station`."""

    @abc.abstractmethod
    def frame(self) -> "AbstractPose | MatrixPose":
        """What a row needs to map points (`to_camera`, `station`), made once per image."""

    @classmethod
    @abc.abstractmethod
    def row_inputs(cls, images: Float[Array, "n_images 6"]) -> PyTree:
        """Per image (leading axis n_images), what `row_frame` needs."""

    @classmethod
    @abc.abstractmethod
    def row_frame(cls, inputs: PyTree, delta: Float[Array, "6"]) -> "AbstractPose | MatrixPose":
        """The frame of one row's image (its `row_inputs`) with the parameters moved by
        `delta`: evaluate at delta = 0 and differentiate by `delta` for the derivatives by
        the image's parameters."""


def per_image(function: Callable[[Array], PyTree], images: Float[Array, "n_images 6"]) -> PyTree:
    """`jax.vmap(function)(images)` (images or mounts: leading axis n_images) made one image
    at a time (`jax.lax.map`), for the rows to gather. Vmapped, XLA fuses the per-image work
    into the gather that reads it per row and recomputes it for every row and entry: an
    omega-phi-kappa derivative's sines and cosines 27 times a row, most of a calibration's
    Jacobian time (5 images of 256 rows: 1.6-2x faster in a loop)."""
    return jax.lax.map(function, images)


def image_frames(pose: type[AbstractPose], images: Float[Array, "n_images 6"]) -> PyTree:
    """`frame()` of every image (leading axis n_images), for the rows to gather."""
    return per_image(lambda values: pose.from_parameters(values).frame(), images)


def image_row_inputs(pose: type[AbstractPose], images: Float[Array, "n_images 6"]) -> PyTree:
    """`pose.row_inputs(images)`, made one image at a time (`per_image`)."""
    return per_image(lambda values: jax.tree.map(lambda x: x[0], pose.row_inputs(values[None])),
                     images)
