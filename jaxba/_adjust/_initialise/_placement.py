"""A model-frame block brought into the object frame (module docstring of `_block`, step 4):
absolute orientation onto control points and given camera stations, one image's given EOPs,
partial control (`partial_similarity`) or only the distances' scale.
"""

import numpy as np

from ..._approximations import Similarity, absolute_orientation
from ..._models._rotation_numpy import matrix_to_opk, opk_to_matrix
from ._frame import partial_similarity


def normalise_model(block, first, second):
    """Move the model so that image `first` is at the origin with M = I and image `second`
    at distance 1 (the refinement moves them a little)."""
    base = np.linalg.norm(block.eops[second, :3] - block.eops[first, :3])
    m = block.matrices[first]
    _apply(block, _similarity(-m @ block.eops[first, :3] / base, m, 1.0 / base))
    block.eops[first] = 0.0
    block.matrices[first] = np.eye(3)


def to_object_frame(block) -> tuple[str, Similarity | None]:
    """Bring a model-frame block into the object frame (module docstring, step 4): by
    `absolute_orientation` onto 3 or more full control points and given stations, else
    onto one image's given EOPs (the scale from the distances or the control), else onto
    partial control (`partial_similarity`), else only scaled by the distances."""
    points = np.flatnonzero(block.known & np.any(np.isfinite(block.control), axis=1))
    stations = np.flatnonzero(block.oriented & np.all(np.isfinite(block.given[:, :3]), axis=1))
    model = np.r_[block.X[points], block.eops[stations, :3]]
    ground = np.r_[block.control[points], block.given[stations, :3]]
    labels = [f"point {p}" for p in points] + [f"image {i}" for i in stations]
    full = np.all(np.isfinite(ground), axis=1)
    similarity = None
    if np.sum(full) >= 3:
        similarity = _absolute(block, model, ground, labels)
    given = np.flatnonzero(block.oriented & np.all(np.isfinite(block.given), axis=1))
    scale, source = _scale(block, model[full], ground[full])
    from_distances = source.endswith("distances")
    if similarity is None and len(given):
        i = given[0]
        r = opk_to_matrix(block.given[i, 3:]).T @ block.matrices[i]  # M_G = M_M Rᵀ
        similarity = _similarity(block.given[i, :3] - scale * r @ block.eops[i, :3], r, scale)
        block.log.append(f"frame: rotated and shifted onto the given EOPs of image {i}, "
                         f"scale {scale:.6g} from {source}")
    if similarity is None and np.sum(np.isfinite(ground)) + from_distances >= 7:
        similarity = _partial(block, model, ground, scale if from_distances else None,
                                   source)
    if similarity is not None:
        _apply(block, similarity)
        return "control", similarity
    if source == "nothing":
        block.log.append("frame: no control, EOPs or distances: the model's (first image "
                         "at the origin, M = I, base 1)")
        return "model", None
    similarity = _similarity(np.zeros(3), np.eye(3), scale)
    block.log.append(f"frame: model scaled by {scale:.6g} from {source}; its origin and axes "
                     "stay the first image's")
    _apply(block, similarity)
    return "model", similarity


def _apply(block, similarity):
    block.eops[block.oriented] = similarity.transform_eops(block.eops[block.oriented])
    block.X[block.known] = similarity.transform(block.X[block.known])
    for i in np.flatnonzero(block.oriented):
        block.matrices[i] = opk_to_matrix(block.eops[i, 3:])


def _partial(block, model, ground, fixed, source) -> Similarity | None:
    """`partial_similarity` onto fewer than 3 full control points (and the distances'
    scale `fixed`, or None); the log says when the control leaves several solutions."""
    solutions = partial_similarity(model, ground, fixed)
    if not solutions:
        return None
    t, r, s, rms = solutions[0]
    count = int(np.sum(np.isfinite(ground)))
    block.log.append(f"frame: similarity onto {count} control coordinates"
                     + (f" with the scale {s:.6g} from {source}" if fixed else
                       f", scale {s:.6g}") + f", RMS {rms:.3g} (object units)")
    if len(solutions) > 1:
        block.log.append(f"frame: WARNING the control fits {len(solutions)} distinct "
                         "rotations equally well (a minimal datum): the first was taken; "
                         "more control coordinates or given EOPs would decide")
    return _similarity(t, r, s)


def _absolute(block, model, ground, labels) -> Similarity | None:
    """`absolute_orientation`, dropping the worst full point while it is off by more than
    5 robust σ (and more than 3 full points remain)."""
    keep = np.ones(len(model), dtype=bool)
    while True:
        try:
            similarity = absolute_orientation(model[keep], ground[keep])
        except (ValueError, np.linalg.LinAlgError) as error:
            block.log.append(f"no absolute orientation ({error})")
            return None
        misfit = np.sqrt(np.nansum(similarity.residuals**2, axis=1))
        full = np.all(np.isfinite(ground[keep]), axis=1)
        spread = 1.4826 * np.median(misfit[full]) + 1e-12 * np.max(np.abs(ground[keep][full]))
        worst = int(np.argmax(np.where(full, misfit, -np.inf)))
        if np.sum(full) > 3 and misfit[worst] > 5 * spread and misfit[worst] > 0:
            index = np.flatnonzero(keep)[worst]
            block.log.append(f"absolute orientation: {labels[index]} is off by "
                             f"{misfit[worst]:.3g} (object units): left out")
            keep[index] = False
            continue
        break
    rms = np.sqrt(np.nanmean(similarity.residuals**2))
    block.log.append(f"frame: absolute orientation onto {int(np.sum(full))} full and "
                     f"{int(np.sum(~full))} partial control points / camera stations, "
                     f"scale {similarity.scale:.6g}, RMS {rms:.3g} (object units)")
    return similarity


def _scale(block, model, ground) -> tuple[float, str]:
    ratios = []
    for a, b, length in block.distances:
        a, b = int(a), int(b)
        if block.known[a] and block.known[b]:
            model_length = np.linalg.norm(block.X[a] - block.X[b])
            if model_length > 0:
                ratios.append(length / model_length)
    if ratios:
        return float(np.median(ratios)), f"{len(ratios)} distances"
    if len(model) >= 2:
        i, j = np.triu_indices(len(model), 1)
        lengths = np.linalg.norm(model[i] - model[j], axis=1)
        usable = lengths > 0
        if np.any(usable):
            ratio = np.linalg.norm(ground[i] - ground[j], axis=1)[usable] / lengths[usable]
            return float(np.median(ratio)), f"{len(model)} control points / stations"
    return 1.0, "nothing"


def _similarity(translation, rotation_matrix, scale) -> Similarity:
    """A `Similarity` X_G = T + S R X_M set by hand (no covariance)."""
    return Similarity(parameters=np.r_[translation, matrix_to_opk(rotation_matrix.T), scale],
                      covariance=np.full((7, 7), np.nan), residuals=np.zeros((0, 3)),
                      variance_factor=float("nan"), redundancy=0, iterations=0,
                      converged=True)
