"""Distortion curves of a camera: one kind of image correction (radial, decentering) along
the radius from the principal point, with its 1σ band from the covariance of that kind's
parameters.

Computed with the camera model itself, for every model alike: the ideal camera is the model
with all its correction terms set to 0 (`DISTORTION_TERMS`), the drawn camera keeps one kind.
For a ray at the angle that puts the ideal image point at radius r from the principal point,
the correction is the drawn camera's image point minus the ideal one (evaluated at the ideal
point where the model corrects the measured point, as SMAC does): the displacement of the
image point by the lens, in the model's image units (mm, or pixels). Its derivatives with
respect to the parameters come from `jax.jacfwd`.
"""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._models._cameras import CAMERA_MODELS, AbstractCamera
from .._models._cameras._names import DISTORTION_TERMS
from ._adjustment import Adjustment
from ._derived import camera_covariance

KINDS = ("radial", "decentering")  # the kinds drawn as curves
_MAX_ANGLE = 0.5 * np.pi * (1 - 1e-9)  # rays up to (nearly) 90° off the axis
_BISECTIONS = 60  # halvings of [0, 90°]: the angle to ~1e-18 rad
_AXIS = np.array([0.0, 0.0, -1.0])  # the camera's axis (photogrammetric frame, looking along -z)


@dataclasses.dataclass(frozen=True)
class DistortionProfile:
    """One kind of correction of one camera along the radius.

    `radius` (n,): from the principal point, image units; `value` (n,): for "radial" the
    displacement along the radius (positive outward) in the +x direction of the camera frame,
    for "decentering" the largest length of the displacement over all directions, image units;
    `std` (n,): its 1σ from the covariance of the kind's parameters (`names`; 0 where they
    are all fixed).
    """

    kind: str
    names: tuple[str, ...]
    radius: np.ndarray
    value: np.ndarray
    std: np.ndarray


def _ray(alpha, phi):
    """Unit ray at `alpha` off the axis, towards `phi` (from camera x towards y)."""
    s = jnp.sin(alpha)
    return jnp.stack([s * jnp.cos(phi), s * jnp.sin(phi), -jnp.cos(alpha)])


def _correction_terms(model: str) -> np.ndarray:
    """(p,) True for the model's correction terms (`DISTORTION_TERMS`), of any kind."""
    return np.isin(CAMERA_MODELS[model].parameter_names,
                   [name for group in DISTORTION_TERMS[model].values() for name in group])


def _with_values(camera: AbstractCamera, values, zero) -> AbstractCamera:
    """`camera` with parameter vector `values`, those where `zero` set to 0."""
    constants = {name: getattr(camera, name) for name in camera.constant_names}
    return type(camera).from_parameters(jnp.where(zero, 0.0, values), **constants)


def _image(camera, ray, measured):
    return camera.image_point(ray, measured, jnp.asarray(0.0))


@eqx.filter_jit
def _ray_angles(ideal: AbstractCamera, radii, phis):
    """Angles (n, m) of the rays that the ideal camera images at `radii` (n,) from its
    principal point towards `phis` (m,), by bisection; and the principal point (2,)."""
    centre = _image(ideal, jnp.asarray(_AXIS), jnp.zeros(2))

    def angle(radius, phi):
        def halve(_, bounds):
            low, high = bounds
            middle = 0.5 * (low + high)
            point = _image(ideal, _ray(middle, phi), jnp.zeros(2))
            beyond = jnp.sum((point - centre) ** 2) > radius**2
            return jnp.where(beyond, low, middle), jnp.where(beyond, middle, high)

        start = (jnp.zeros_like(radius), jnp.full_like(radius, _MAX_ANGLE))
        low, high = jax.lax.fori_loop(0, _BISECTIONS, halve, start)
        return 0.5 * (low + high)

    return jax.vmap(jax.vmap(angle, (None, 0)), (0, None))(radii, phis), centre


@eqx.filter_jit
def _displacements(camera: AbstractCamera, others, terms, angles, phis):
    """Image displacement (n, m, 2) by the terms the drawn camera keeps (`others`: the
    correction terms it sets to 0; `terms`: all of them), its Jacobian (n, m, 2, p) with
    respect to the parameter vector, and the ideal image points (n, m, 2)."""
    ideal_camera = _with_values(camera, camera.parameters(), terms)
    rays = jax.vmap(jax.vmap(_ray))(angles, jnp.broadcast_to(phis, angles.shape))
    ideal = jax.vmap(jax.vmap(lambda ray: _image(ideal_camera, ray, jnp.zeros(2))))(rays)

    def displaced(values):
        drawn = _with_values(camera, values, others)
        return jax.vmap(jax.vmap(lambda ray, at: _image(drawn, ray, at)))(rays, ideal) - ideal

    values = camera.parameters()
    return displaced(values), jax.jacfwd(displaced)(values), ideal


def correction_profile(
    camera: AbstractCamera, model: str, kind: str, radii, *, directions: int = 72
) -> tuple[np.ndarray, np.ndarray]:
    """One kind of correction of `camera` (a camera of `model`) at `radii` (n,) image units
    from the principal point: (value (n,), Jacobian (n, p) with respect to the camera's
    parameter vector). See `DistortionProfile` for what "radial" and "decentering" give;
    the largest decentering is searched over `directions` equally spaced directions."""
    terms_of = DISTORTION_TERMS[model]
    if kind not in terms_of:
        raise ValueError(f"camera model {model!r} has no {kind} terms; it has {list(terms_of)}")
    terms = _correction_terms(model)
    others = terms & ~np.isin(CAMERA_MODELS[model].parameter_names, terms_of[kind])
    radii = jnp.asarray(radii, dtype=float)
    # Both kinds on the same rays (the radial one reads direction 0): one compiled program.
    phis = jnp.arange(directions) * (2 * np.pi / directions)
    ideal_camera = _with_values(camera, camera.parameters(), jnp.asarray(terms))
    angles, centre = _ray_angles(ideal_camera, radii, phis)
    shift, jacobian, ideal = (np.asarray(a) for a in _displacements(
        camera, jnp.asarray(others), jnp.asarray(terms), angles, phis))
    if kind == "radial":
        offset = ideal[:, 0] - np.asarray(centre)
        length = np.linalg.norm(offset, axis=-1, keepdims=True)
        unit = np.divide(offset, length, out=np.zeros_like(offset), where=length > 0)
        return (np.einsum("nk,nk->n", unit, shift[:, 0]),
                np.einsum("nk,nkp->np", unit, jacobian[:, 0]))
    length = np.linalg.norm(shift, axis=-1)
    widest = np.argmax(length, axis=1)
    rows = np.arange(len(widest))
    largest, vector = length[rows, widest], shift[rows, widest]
    unit = np.divide(vector, largest[:, None], out=np.zeros_like(vector),
                     where=largest[:, None] > 0)
    return largest, np.einsum("nk,nkp->np", unit, jacobian[rows, widest])


def principal_point(camera: AbstractCamera, model: str) -> np.ndarray:
    """(2,) where the ideal camera (all correction terms 0) images the camera's axis, image
    units: the principal point."""
    ideal = _with_values(camera, camera.parameters(), jnp.asarray(_correction_terms(model)))
    return np.asarray(_image(ideal, jnp.asarray(_AXIS), jnp.zeros(2)))


def distortion_profiles(
    result: Adjustment, model: str, row: int, corners, *,
    constants: dict[str, float] | None = None, n: int = 101,
) -> dict[str, DistortionProfile]:
    """The radial and decentering curves (those of `KINDS` that the model has) of camera
    `row` of `model` at the solution, at `n` radii from 0 to the farthest of `corners` (k, 2)
    (image points, e.g. the sensor's corners) from the principal point, with 1σ from Cxx of
    each kind's parameters; `constants`: the model's constants (e.g. {"r0": 12.5} for
    "metrology")."""
    names = CAMERA_MODELS[model].parameter_names
    values = jnp.asarray(np.asarray(result.parameters.cameras[model])[row], dtype=float)
    camera = CAMERA_MODELS[model].from_parameters(values, **(constants or {}))
    offsets = np.asarray(corners, dtype=float).reshape(-1, 2) - principal_point(camera, model)
    radii = np.linspace(0.0, float(np.max(np.linalg.norm(offsets, axis=1))), n)
    covariance = camera_covariance(result, model, row)
    profiles = {}
    for kind in (k for k in KINDS if k in DISTORTION_TERMS[model]):
        value, jacobian = correction_profile(camera, model, kind, radii)
        chosen = np.isin(names, DISTORTION_TERMS[model][kind])
        part = jacobian[:, chosen]
        variance = np.einsum("np,pq,nq->n", part, covariance[np.ix_(chosen, chosen)], part)
        profiles[kind] = DistortionProfile(
            kind, DISTORTION_TERMS[model][kind], radii, value, np.sqrt(np.clip(variance, 0, None)))
    return profiles
