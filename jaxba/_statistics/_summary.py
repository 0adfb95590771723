"""What an adjustment says in a few lines, like Ceres' BriefReport: convergence, σ̂0 and its
χ² test, redundancy, the datum, the backend, the outliers, the timings and every camera's
estimated parameters with their σ.

The console, NAME.out and results.json report the same facts from these functions.
"""

import dataclasses
import math

import numpy as np

from .._problem._observations import host_query, part_name
from .._problem._parameters import flatten, positions_of
from ._free_network import inner_constraint_group
from ._ids import Ids
from ._observation_statistics import (
    describe,
    group_statistics,
    observation_ids,
    outliers,
)

VARIANCE_TEST_ALPHA = 0.05  # two-sided χ² test of the variance factor
LISTED = 5  # outliers named, the largest |w| first


@dataclasses.dataclass(frozen=True)
class VarianceTest:
    """The global test of the variance factor: T = r σ̂0² / σ0² is χ²(r) distributed when
    the model and the a priori σ are right; it passes inside [χ²(r; α/2), χ²(r; 1 - α/2)].

    `sigma0_low`, `sigma0_high`: the σ̂0 that bound the interval, σ0 sqrt(χ²/r).
    """

    redundancy: int
    sigma0: float
    sigma0_prior: float
    alpha: float
    statistic: float
    low: float
    high: float

    @property
    def passed(self) -> bool:
        return bool(self.low <= self.statistic <= self.high)

    @property
    def sigma0_low(self) -> float:
        return self.sigma0_prior * math.sqrt(self.low / self.redundancy)

    @property
    def sigma0_high(self) -> float:
        return self.sigma0_prior * math.sqrt(self.high / self.redundancy)

    def text(self) -> str:
        """E.g. `chi-square test passed: r sigma0^2/prior^2 = 2433.7 in [2308.9, 2582.9]
        (redundancy 2444, alpha 0.05: sigma0 0.972 to 1.028)`; where it fails, "FAILED"
        and "not in" the interval."""
        verdict, where = ("passed", "in") if self.passed else ("FAILED", "not in")
        return (f"chi-square test {verdict}: r sigma0^2/prior^2 = {self.statistic:.1f} {where}"
                f" [{self.low:.1f}, {self.high:.1f}] (redundancy {self.redundancy}, alpha"
                f" {self.alpha:g}: sigma0 {self.sigma0_low:.4g} to {self.sigma0_high:.4g})")


def variance_test(result, alpha: float = VARIANCE_TEST_ALPHA) -> VarianceTest | None:
    """The two-sided χ² test of `result`'s σ̂0 against its a priori σ0 at `alpha`; None
    without redundancy or without a finite σ̂0."""
    precision = result.precision
    r = int(precision.redundancy)
    if r <= 0 or not math.isfinite(precision.sigma0_squared):
        return None
    import scipy.special  # here: scipy.stats, for chi2.ppf alone, took 0.8 s to import

    prior = float(result.sigma0_prior)
    low, high = 2 * scipy.special.gammaincinv(r / 2, [alpha / 2, 1 - alpha / 2])  # χ² ppf
    return VarianceTest(r, math.sqrt(precision.sigma0_squared), prior, alpha,
                        r * precision.sigma0_squared / prior**2, float(low), float(high))


def datum_description(problem) -> str:
    """How the datum is defined, e.g. "free network: inner constraints (7 conditions) over 80
    points" or "control: 3 control points (6 fixed, 0 weighted coordinates), 4 distances"."""
    positions = positions_of(problem.initial)
    point_positions = np.asarray(positions.points)
    inner = inner_constraint_group(problem)
    if inner is not None:
        touched = np.asarray(inner.directions)[:, point_positions.ravel()] != 0
        n_points = int(touched.any(axis=0).reshape(-1, 3).any(axis=1).sum())
        return (f"free network: inner constraints ({np.shape(inner.directions)[0]} conditions)"
                f" over {n_points} points")
    free = flatten(problem.free).astype(bool)
    weighted = np.zeros(free.shape, dtype=bool)
    for group in problem.groups:
        weighted[host_query(group, "prior_positions", positions)] = True
    fixed_xyz, weighted_xyz = ~free[point_positions], weighted[point_positions]
    control = (fixed_xyz | weighted_xyz).any(axis=1)
    parts = []
    if control.any():
        parts.append(f"{int(control.sum())} control points ({int(fixed_xyz.sum())} fixed,"
                     f" {int(weighted_xyz.sum())} weighted coordinates)")
    image_positions = np.asarray(positions.images)
    for what, mask in (("fixed", ~free[image_positions]), ("weighted", weighted[image_positions])):
        n_images = int(mask.any(axis=1).sum())
        if n_images:
            parts.append(f"{n_images} images with {what} EOPs")
    n_distances = sum(int(np.isfinite(np.asarray(g.stddev)).sum()) for g in problem.groups
                      if host_query(g, "kind") == "distances")
    if n_distances:
        parts.append(f"{n_distances} distances")
    return "control: " + (", ".join(parts) if parts else "none (no fixed or weighted unknowns)")


@dataclasses.dataclass(frozen=True)
class OutlierSummary:
    """The observations the final solution used with |w| above `critical_value` (the
    reliability's w-test at per-test `alpha`): their `count` and the `worst` few as (group,
    observation, |w|), largest first (e.g. ("image_points:C1", "image img01 point 5 x",
    6.1)); `removed`: rejected by data snooping."""

    critical_value: float
    alpha: float
    count: int
    worst: list[tuple[str, str, float]]
    removed: int

    def text(self) -> str:
        named = ", ".join(f"{group} {name} |w| {abs_w:.2f}" for group, name, abs_w in self.worst)
        more = f" and {self.count - len(self.worst)} more" if self.count > len(self.worst) else ""
        removed = f"; {self.removed} removed by data snooping" if self.removed else ""
        found = f": {named}{more}" if self.count else ""
        return (f"{self.count} with |w| > {self.critical_value:.2f} (alpha {self.alpha:.3g} per"
                f" test){found}{removed}")


def outlier_summary(result, ids: Ids, statistics=None,
                    listed: int = LISTED) -> OutlierSummary | None:
    """`OutlierSummary` of `result` naming observations by `ids` (`statistics`: its
    `group_statistics`, computed when None); None without a reliability."""
    if result.reliability is None:
        return None
    found = outliers(result, group_statistics(result) if statistics is None else statistics)
    groups = result.problem.groups

    worst = [
        (part_name(groups[o.group], ids.cameras, o.row),
         describe(observation_ids(ids, groups[o.group], o.row, o.coordinate)), o.abs_w)
        for o in found[:listed]
    ]
    return OutlierSummary(float(result.reliability.critical_value),
                          float(result.reliability.alpha), len(found), worst,
                          len(result.rejections))


def statistical_items(result, ids: Ids, statistics=None, datum: str | None = None,
                      test: VarianceTest | None = None,
                      found: OutlierSummary | None = None) -> list[tuple[str, str]]:
    """(name, text) of the variance test, the datum, the outliers and the timings: the lines
    `brief_report` and NAME.out share (`statistics`: as `outlier_summary`). `datum`, `test`
    and `found`: the datum's description, `variance_test` and `outlier_summary` where the
    caller has them (computed when None)."""
    test = variance_test(result) if test is None else test
    found = outlier_summary(result, ids, statistics) if found is None else found
    return [
        ("variance test", test.text() if test is not None else "not available"),
        ("datum", datum_description(result.problem) if datum is None else datum),
        ("outliers", found.text() if found is not None else "no reliability computed"),
        ("timings", result.timings.text() if result.timings.phases else "not timed"),
    ]


def aligned(items: list[tuple[str, str]], prefix: str = "") -> list[str]:
    """`prefix key  value` lines, the values aligned."""
    width = max(len(key) for key, _ in items)
    return [f"{prefix}{key.ljust(width)}  {value}" for key, value in items]


def camera_lines(result) -> list[str]:
    """`camera ID (model)` and a line `  name  value +/- σ` per estimated (free or weighted)
    parameter of each camera of `result` (an `Adjustment`), in the model's order and units."""
    lines = []
    for cid, estimates in result.cameras.items():
        shown = {name: e for name, e in estimates.items() if e.status != "fixed"}
        if not shown:
            continue
        lines.append(f"camera {cid} ({estimates.model})")
        width = max(len(name) for name in shown)
        for name, estimate in shown.items():
            sigma = "n/a" if estimate.sigma is None else f"{estimate.sigma:.2e}"
            note = "" if estimate.status == "free" else f"  ({estimate.status})"
            lines.append(f"  {name.ljust(width)}  {estimate.value: .8e} +/- {sigma}{note}")
    return lines


def brief_report(result, ids: Ids) -> str:
    """A few lines on `result` (an `Adjustment`): see the module docstring."""
    precision = result.precision
    state = "converged" if result.converged else f"NOT converged ({result.message})"
    items = [
        ("solver", f"{state} after {result.n_iterations} iterations ({result.steps} steps),"
                   f" {result.backend} backend"),
        ("sigma0", f"{result.sigma0:.6g} (a priori {result.sigma0_prior:g})"),
        ("observations", f"{precision.n_observations}, unknowns {precision.n_unknowns},"
                         f" redundancy {precision.redundancy}"),
        *statistical_items(result, ids),
    ]
    return "\n".join([*aligned(items), *camera_lines(result)]) + "\n"
