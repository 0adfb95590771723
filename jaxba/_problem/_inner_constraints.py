"""Inner constraints: the observation group that fixes a free network's datum."""

from typing import ClassVar

import equinox as eqx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float

from .._models._cameras import AbstractRefraction
from ._observations import AbstractObservationGroup
from ._parameters import Parameters


class InnerConstraints(AbstractObservationGroup):
    """d constraints Bᵀ (x - x₀) = 0 on the flattened unknowns (`flatten` order).

    `directions` (d, n_all) holds the rows of Bᵀ, `reference` (n_all,) x₀; `similarity`
    (7, d) the unobservable similarity motions (their coefficients in
    `jaxba._statistics._datum.similarity_transform`'s (t, a, s)), `centre` (3,) the
    similarity's fixed point, `pose` the images' pose model (how the similarity turns
    them). Every row depends on every unknown: not row-local (no `row_blocks`).
    """

    directions: Float[Array, "d n_all"]
    reference: Float[Array, " n_all"]
    stddev: Float[Array, "d 1"]
    similarity: Float[Array, "7 d"]
    centre: Float[Array, " 3"]
    name: str = eqx.field(static=True, default="inner_constraints")
    pose: str = eqx.field(static=True, default="opk")
    constraint: ClassVar[bool] = True

    def residuals(self, params: Parameters, refraction: AbstractRefraction) -> Array:
        del refraction
        flat = ravel_pytree(params)[0]
        return -(self.directions @ (flat - self.reference))[:, None] / self.stddev
