"""A board's warp in the reports: kx, ky (object units) with σ, their correlation, and the
correlations of each with every camera's estimated IOPs (a warp that trades with a focal
length or a distortion term shows there)."""

import dataclasses

import numpy as np

from .._models._cameras import CAMERA_MODELS
from .._problem._parameters import WARP_PARAMETER_NAMES, positions_of
from .._project._build import Project
from .._statistics._adjustment import Adjustment
from .._statistics._derived import correlation
from ._collect import shared


@dataclasses.dataclass(frozen=True)
class BoardWarp:
    """The warp of each board: `ids` (n_boards,), `values` and `stds` (n_boards, 2) kx, ky
    in object units; `rho` (n_boards,) ρ(kx, ky); `cameras` {camera: (its estimated IOPs'
    names, ρ (n_boards, 2, p) of kx and ky with each)}."""

    ids: tuple[str, ...]
    values: np.ndarray
    stds: np.ndarray
    rho: np.ndarray
    cameras: dict[str, tuple[list[str], np.ndarray]]


@shared
def board_warp(project: Project, result: Adjustment) -> BoardWarp | None:
    """The boards' warp (`BoardWarp`), None where no board is warped."""
    params = result.parameters
    if params.warp is None:
        return None
    positions = positions_of(params)
    warp = np.asarray(positions.warp)
    rho, cameras = [], {}
    for board in range(warp.shape[0]):
        rho.append(correlation(result.precision.covariance_of(warp[board]))[0, 1])
    for cid, (model, row) in project.camera_rows.items():
        free = np.asarray(project.problem.free.cameras[model])[row]
        iop = np.asarray(positions.cameras[model])[row][free]
        names = [n for n, f in zip(CAMERA_MODELS[model].parameter_names, free) if f]
        blocks = []
        for board in range(warp.shape[0]):
            rho_all = correlation(result.precision.covariance_of(
                np.concatenate([warp[board], iop])))
            blocks.append(rho_all[:2, 2:])
        cameras[cid] = (names, np.array(blocks).reshape(warp.shape[0], 2, len(names)))
    return BoardWarp(tuple(project.board_ids), np.asarray(params.warp, dtype=float),
                     np.asarray(result.precision.std.warp, dtype=float), np.asarray(rho),
                     cameras)


def board_warp_tree(project: Project, result: Adjustment) -> dict | None:
    """results.json "board_warp" of the project's one board: {"kx": {"value", "std"}, "ky":
    ..., "units", "correlation" ρ(kx, ky), "camera_correlations": {camera: {"parameters":
    [...], "kx": [ρ ...], "ky": [ρ ...]}}}; None without a warp."""
    warp = board_warp(project, result)
    if warp is None:
        return None
    tree = {name: {"value": float(warp.values[0, k]), "std": float(warp.stds[0, k])}
            for k, name in enumerate(WARP_PARAMETER_NAMES)}
    tree["units"] = "object units of the input files"
    tree["correlation"] = float(warp.rho[0])
    tree["camera_correlations"] = {
        cid: {"parameters": names,
              **{name: rho[0, k].tolist() for k, name in enumerate(WARP_PARAMETER_NAMES)}}
        for cid, (names, rho) in warp.cameras.items()}
    return tree
