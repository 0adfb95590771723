"""The unknowns without a σ (`Adjustment.no_sigma`) as the reports name them."""

from .._project._build import Project
from .._statistics._adjustment import Adjustment

LISTED = 10


def no_sigma_entries(project: Project, result: Adjustment) -> list[dict[str, str]]:
    """[{"unknown": label ("point 17 X"), "reason": why}] in `flatten` order."""
    return [{"unknown": project.labels[position], "reason": reason}
            for position, reason in sorted(result.no_sigma.items())]


def no_sigma_lines(project: Project, result: Adjustment) -> list[str]:
    """One line per reason: "no sigma for 3 unknowns (point 17 X, point 17 Y, point 17 Z):
    why; every other unknown has its sigma"; none where every unknown has its σ."""
    by_reason: dict[str, list[str]] = {}
    for entry in no_sigma_entries(project, result):
        by_reason.setdefault(entry["reason"], []).append(entry["unknown"])
    lines = []
    for reason, labels in by_reason.items():
        named = ", ".join(labels[:LISTED])
        more = f" and {len(labels) - LISTED} more" if len(labels) > LISTED else ""
        lines.append(f"no sigma for {len(labels)} unknown(s) ({named}{more}): {reason};"
                     " every other unknown has its sigma")
    return lines
