"""Name the cause of a failed check or solve in the terms of the data: which points are not
intersected (one image, one projection centre, near-parallel rays), which observations are
not finite at the approximations, which approximations an adjustment diverged from.

Only called once something has failed, so a correct project pays nothing; all O(n_obs)
(no Jacobian), so the Schur backend's large bundles can afford them too.
"""

import jax
import numpy as np

from .._models._poses import POSE_MODELS
from .._problem._bundle import BundleProblem
from .._problem._parameters import flatten, positions_of, unflatten

# Rays to a point that all lie within this angle of each other (degrees, an upper bound of
# the largest pairwise angle) do not intersect it for the datum check: a Jacobian
# condition of 1e6 (the Schur check's threshold) is reached near 1e-6 rad.
PARALLEL_DEGREES = 1e-3
# Two projection centres closer than this fraction of the network's extent are one.
SAME_STATION = 1e-9
# A solve that stops unconverged with σ̂0 above this multiple of the a priori σ0 is
# reported as diverged from its approximations rather than as merely slow.
DIVERGED_SIGMA0 = 10.0
_NAMED = 5  # ids named in a message before "and n more"


def _stations(problem: BundleProblem) -> np.ndarray:
    """(n_images, 3) the projection centres X0 of the approximations (by the pose model)."""
    model = POSE_MODELS[problem.pose]
    poses = jax.vmap(model.from_parameters)(problem.initial.images)
    return np.asarray(jax.vmap(model.station)(poses))


def _listing(names: list[str], limit: int = _NAMED) -> str:
    """"a", "a and b", "a, b and c", "a, b, c, d, e and 4 more"."""
    if len(names) > limit:
        return ", ".join(names[:limit]) + f" and {len(names) - limit} more"
    return " and ".join([", ".join(names[:-1]), names[-1]]) if len(names) > 1 else names[0]


def entity_ids(problem: BundleProblem, labels: list[str]) -> tuple[list[str], list[str]]:
    """The image and point ids, read from `labels` ("image img01 X0" -> "img01")."""
    positions = positions_of(problem.initial)

    def ids(rows):
        return [labels[int(k)].split(" ", 1)[1].rsplit(" ", 1)[0] for k in rows]

    return ids(np.asarray(positions.images)[:, 0]), ids(np.asarray(positions.points)[:, 0])


def _image_rows(problem: BundleProblem) -> tuple[np.ndarray, np.ndarray]:
    """(image, point) of every real image observation (rows with a finite σ)."""
    images, points = [np.zeros(0, int)], [np.zeros(0, int)]
    for group in problem.groups:
        if group.kind() == "image_points":
            real = np.asarray(group.mask()).any(axis=1)
            images.append(np.asarray(group.image)[real])
            points.append(np.asarray(group.point)[real])
    return np.concatenate(images), np.concatenate(points)


def _unconstrained_points(problem: BundleProblem) -> np.ndarray:
    """(n_points,) True for points with three free coordinates and no control observation:
    those that only rays can determine."""
    positions = positions_of(problem.initial)
    observed = np.concatenate([np.zeros(0, int)] + [
        group.prior_positions(positions) for group in problem.groups])
    controlled = np.isin(np.asarray(positions.points), observed).any(axis=1)
    return np.asarray(problem.free.points).all(axis=1) & ~controlled


def intersection_cause(
    problem: BundleProblem, labels: list[str], suspects: np.ndarray | None = None
) -> str | None:
    """Why points cannot be intersected at the approximations, or None: points observed in
    one image only, points seen from one projection centre only (images with the same
    station), rays nearly parallel (`PARALLEL_DEGREES`). `suspects` (n_points,): only these
    points (e.g. those a rank defect involves)."""
    image, point = _image_rows(problem)
    candidates = _unconstrained_points(problem)
    if suspects is not None:
        candidates &= suspects
    if not candidates.any():
        return None
    n_points = candidates.size
    pairs = np.unique(np.stack([image, point], 1), axis=0)
    pairs = pairs[candidates[pairs[:, 1]]]
    image, point = pairs[:, 0], pairs[:, 1]
    stations = _stations(problem)
    xyz = np.asarray(problem.initial.points)
    extent = np.max(np.ptp(np.concatenate([stations, xyz]), axis=0))
    tolerance = SAME_STATION * max(extent, np.finfo(float).tiny)
    _, station = np.unique(np.round(stations / tolerance), axis=0, return_inverse=True)
    station = station.ravel()
    n_images = np.bincount(point, minlength=n_points)
    station_pairs = np.unique(np.stack([station[image], point], 1), axis=0)
    n_stations = np.bincount(station_pairs[:, 1], minlength=n_points)
    image_ids, point_ids = entity_ids(problem, labels)
    causes = []

    single = np.flatnonzero(candidates & (n_images == 1))
    if single.size:
        named = [f"{point_ids[p]} ({image_ids[image[point == p][0]]})" for p in single]
        causes.append(
            f"point {named[0]} is observed in only one image" if single.size == 1
            else f"points {_listing(named)} are each observed in only one image")

    one_station = candidates & (n_images >= 2) & (n_stations == 1)
    for where in np.unique(station[image[one_station[point]]]):
        members = np.flatnonzero(station == where)
        seen = [point_ids[p] for p in np.flatnonzero(one_station)
                if station[image[point == p][0]] == where]
        centre = ", ".join(f"{v:.6g}" for v in stations[members[0]])
        who = (f"all {members.size} images have" if members.size == stations.shape[0]
               else f"images {_listing([image_ids[i] for i in members])} have")
        causes.append(
            f"{who} the same projection centre ({centre}): point{'s' * (len(seen) > 1)}"
            f" {_listing(seen)} {'is' if len(seen) == 1 else 'are'} seen from that station"
            " only and cannot be intersected")

    rays = xyz[point] - stations[image]
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    mean = np.zeros((n_points, 3))
    np.add.at(mean, point, rays)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), np.finfo(float).tiny)
    angle = np.arccos(np.clip(np.sum(rays * mean[point], axis=1), -1.0, 1.0))
    spread = np.zeros(n_points)
    np.maximum.at(spread, point, angle)
    spread = np.degrees(2 * spread)  # ≥ every pairwise angle
    parallel = np.flatnonzero(candidates & (n_stations >= 2) & (spread < PARALLEL_DEGREES))
    if parallel.size:
        worst = parallel[np.argsort(spread[parallel])]
        named = [f"{point_ids[p]} (< {spread[p]:.2g}°)" for p in worst]
        causes.append(
            f"the rays to point{'s' * (parallel.size > 1)} {_listing(named)} are nearly"
            " parallel at the approximations, intersecting at less than"
            f" {PARALLEL_DEGREES:g}°")
    return "; ".join(causes) or None


def nonfinite_observations(problem: BundleProblem, whitened, labels: list[str]) -> str | None:
    """The observations whose whitened residuals (`whitened`, per group) are not finite,
    named ("image img01 point 7", "distances row 3"), or None."""
    image_ids, point_ids = entity_ids(problem, labels)
    named = []
    for group, e in zip(problem.groups, whitened):
        bad = np.flatnonzero(~np.isfinite(np.asarray(e)).all(axis=1)
                             & np.asarray(group.mask()).any(axis=1))
        if group.kind() == "image_points":
            image, point = np.asarray(group.image), np.asarray(group.point)
            named += [f"image {image_ids[image[k]]} point {point_ids[point[k]]}" for k in bad]
        else:
            named += [f"{group.name} row {k + 1}" for k in bad]
    return _listing(named) if named else None


def divergence_cause(
    problem: BundleProblem,
    params,
    std,
    whitened,
    labels: list[str],
) -> str:
    """Which approximations a solve that did not converge moved away from most, and which
    images keep the largest residuals: "the adjustment diverged from the approximations of
    image img03 kappa (4.1e+04 σ), ...; the largest residuals are in images img03 (RMS
    812 σ), ...". The moves are in σ at the final iterate where it has them, otherwise
    relative to the unknown's size (positions: the network's extent, angles: π)."""
    index = np.flatnonzero(flatten(problem.free))
    start = flatten(problem.initial)[index]
    moved = np.abs(flatten(params)[index] - start)
    sigma = np.asarray(flatten(std), dtype=float)[index]
    if np.all(np.isfinite(sigma) & (sigma > 0)):
        size, unit = sigma, np.full(index.size, "σ", dtype=object)
    else:  # no σ (a singular normal matrix): relative to the unknown's size
        n_all = flatten(problem.initial).size
        positions = unflatten(problem.initial, np.arange(n_all))
        corners = np.concatenate([_stations(problem), np.asarray(problem.initial.points)])
        extent = np.max(np.ptp(corners, axis=0))
        kind, unit = np.zeros(n_all), np.full(n_all, "its approximation", dtype=object)
        for rows, value, name in (
            (np.asarray(positions.images)[:, :3], extent, "the network's extent"),
            (np.asarray(positions.points), extent, "the network's extent"),
            (np.asarray(positions.images)[:, 3:], np.pi, "π"),
        ):
            kind[rows.ravel()], unit[rows.ravel()] = value, name
        size = np.where(kind[index] > 0, kind[index], np.maximum(np.abs(start), 1.0))
        unit = unit[index]
    relative = np.where(np.isfinite(moved), moved / size, np.inf)
    order = np.argsort(-relative)[:3]
    unknowns = ", ".join(
        f"{labels[index[k]]} (moved {relative[k]:.2g}{' ' if unit[k] == 'σ' else ' × '}"
        f"{unit[k]})" for k in order)
    image_ids, _ = entity_ids(problem, labels)
    squares, counts = np.zeros(len(image_ids)), np.zeros(len(image_ids))
    for group, e in zip(problem.groups, whitened):
        if group.kind() == "image_points":
            mask = np.asarray(group.mask())
            e = np.where(mask, np.asarray(e), 0.0)
            np.add.at(squares, np.asarray(group.image), np.sum(e**2, axis=1))
            np.add.at(counts, np.asarray(group.image), np.sum(mask, axis=1))
    rms = np.sqrt(squares / np.maximum(counts, 1))
    worst = np.argsort(-rms)[:3]
    images = ", ".join(f"{image_ids[i]} (RMS {rms[i]:.3g} σ)" for i in worst if counts[i])
    return (f"the adjustment diverged from the approximations of {unknowns}"
            + (f"; the largest residuals are in images {images}" if images else "")
            + ": check these approximations")
