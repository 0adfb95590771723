"""Baarda's data snooping: test every observation's w, remove the worst, re-adjust, repeat."""

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._problem._bundle import BundleProblem
from .._statistics._adjustment import Adjustment
from .._statistics._reliability import Reliability, reliability
from ._adjust import adjust


@dataclasses.dataclass(frozen=True)
class Rejection:
    """An observation removed by data snooping: group name, row, coordinate and its |w|."""

    group: str
    row: int
    coordinate: int
    w: float


def remove_observation(problem: BundleProblem, group_index: int, row: int, coordinate: int):
    """The problem with one observation switched off (σ = inf).

    An image point is removed whole (x and y; the group's `removed_whole`): a wrong
    measurement is wrong in both.
    """
    group = problem.groups[group_index]
    columns = slice(None) if group.removed_whole else coordinate
    stddev = group.stddev.at[row, columns].set(jnp.inf)
    groups = list(problem.groups)
    groups[group_index] = eqx.tree_at(lambda g: g.stddev, group, stddev)
    return eqx.tree_at(lambda p: p.groups, problem, tuple(groups))


def restart_from(problem: BundleProblem, params) -> BundleProblem:
    """The problem with `params` as its approximations (fixed values are unchanged)."""
    return eqx.tree_at(lambda p: p.initial, problem, params)


def data_snooping(
    result: Adjustment,
    *,
    alpha: float = 0.001,
    familywise: bool = False,
    max_rejections: int = 50,
    **adjust_options,
) -> tuple[Adjustment, list[Rejection], Reliability]:
    """Baarda's iterative data snooping.

    Test every observation's w against the two-sided normal critical value at `alpha`
    (per test, or family-wise over all tests with `familywise=True`); remove the worst
    one above it, re-adjust from the current solution, and repeat.
    Returns the final adjustment, the rejected observations in order, and the final
    reliability. `adjust_options` go to `adjust` (sigma0, max_steps, ...).
    """
    rejections: list[Rejection] = []
    current = result
    while True:
        report = reliability(current, alpha=alpha, familywise=familywise)
        worst = [
            (np.nanmax(np.abs(w)) if np.isfinite(w).any() else 0.0, k)
            for k, w in enumerate(report.normalised_residuals)
        ]
        size, group_index = max(worst)
        if size <= report.critical_value or len(rejections) >= max_rejections:
            return current, rejections, report
        w = np.abs(np.nan_to_num(report.normalised_residuals[group_index], nan=0.0))
        row, coordinate = np.unravel_index(np.argmax(w), w.shape)
        group = current.problem.groups[group_index]
        rejections.append(Rejection(group.name, int(row), int(coordinate), float(size)))
        problem = remove_observation(current.problem, group_index, int(row), int(coordinate))
        current = adjust(restart_from(problem, current.parameters), check=False, **adjust_options)
