"""Observation groups: each is one per-observation residual function vmapped over the group.

Residuals are whitened, e = (observed - computed) / σ, so that the solver minimises
½ Σ e² = ½ vᵀ Σ⁻¹ v. Every group reports which residual entries are real observations
(`mask`), so that padding entries (a coordinate with no observation) count nowhere.
"""

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ._camera import CAMERA_MODELS, AbstractRefraction
from ._custom_types import Vector2, Vector3
from ._parameters import Parameters
from ._rotation import opk_to_matrix


class AbstractObservationGroup(eqx.Module):
    """A set of observations of one kind.

    `stddev` holds the a priori σ of every residual entry (units of the observation);
    σ = inf marks an entry that is not an observation (an unobserved coordinate, or a
    measurement removed as a blunder): it is whitened to 0 and counted nowhere.
    """

    name: eqx.AbstractVar[str]
    stddev: eqx.AbstractVar[Float[Array, "n k"]]

    @abc.abstractmethod
    def residuals(self, params: Parameters, refraction: AbstractRefraction) -> Array:
        """Whitened residuals (observed - computed) / σ, shape (n, k)."""

    def mask(self) -> Bool[Array, "n k"]:
        """True where the residual entry is an observation."""
        return jnp.isfinite(self.stddev)

    def sigma(self) -> Float[Array, "n k"]:
        """A priori σ of every residual entry."""
        return self.stddev


def collinearity_residual(
    model: str,
    iop: Float[Array, " n_iop"],
    eop: Float[Array, " 6"],
    point: Vector3,
    measured: Vector2,
    sigma: Vector2,
    refraction: AbstractRefraction,
) -> Vector2:
    """Whitened image residual (x_obs - x, y_obs - y) / σ of one measured image point."""
    camera = CAMERA_MODELS[model].from_parameters(iop)
    station = eop[:3]
    p_camera = opk_to_matrix(eop[3:]) @ (point - station)
    k = refraction.coefficient(station, point)
    return (measured - camera.image_point(p_camera, measured, k)) / sigma


class ImagePoints(AbstractObservationGroup):
    """Image coordinates of points, all taken with cameras of one model.

    `camera`, `image`, `point` index the rows of `cameras[model]`, `images`, `points`;
    `measured` and `stddev` are (n, 2) in the camera model's image units.
    """

    name: str = eqx.field(static=True)
    model: str = eqx.field(static=True)
    camera: Int[Array, " n"]
    image: Int[Array, " n"]
    point: Int[Array, " n"]
    measured: Float[Array, "n 2"]
    stddev: Float[Array, "n 2"]

    def residuals(self, params: Parameters, refraction: AbstractRefraction) -> Float[Array, "n 2"]:
        def one(iop, eop, point, measured, sigma):
            return collinearity_residual(self.model, iop, eop, point, measured, sigma, refraction)

        return jax.vmap(one)(
            params.cameras[self.model][self.camera],
            params.images[self.image],
            params.points[self.point],
            self.measured,
            self.stddev,
        )


class ParameterObservations(AbstractObservationGroup):
    """Direct observations of parameters: control coordinates, GNSS/INS EOPs, IOP priors.

    `rows` index the block `block` ("points", "images" or "cameras/<model>"); `observed`
    and `stddev` have the block's width, with σ = inf where an entry is not observed.
    """

    name: str = eqx.field(static=True)
    block: str = eqx.field(static=True)
    rows: Int[Array, " n"]
    observed: Float[Array, "n k"]
    stddev: Float[Array, "n k"]

    def residuals(self, params: Parameters, refraction: AbstractRefraction) -> Float[Array, "n k"]:
        del refraction
        return (self.observed - params.block(self.block)[self.rows]) / self.stddev


class Distances(AbstractObservationGroup):
    """Measured distances between object points `a` and `b` (object units)."""

    name: str = eqx.field(static=True)
    a: Int[Array, " n"]
    b: Int[Array, " n"]
    observed: Float[Array, "n 1"]
    stddev: Float[Array, "n 1"]

    def residuals(self, params: Parameters, refraction: AbstractRefraction) -> Float[Array, "n 1"]:
        del refraction
        difference = params.points[self.a] - params.points[self.b]
        computed = jnp.sqrt(jnp.sum(difference**2, axis=1, keepdims=True))
        return (self.observed - computed) / self.stddev
