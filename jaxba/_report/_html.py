"""The adjustment as one self-contained HTML page: summary, tables and the report's figures.

Readable offline: the style sheet is inline, the figures are embedded as base64 PNG, no
scripts, no external address. Each value is written to the second significant digit of its σ.
"""

import base64
import html
import io
import math

import numpy as np

from .._problem._observations import part_name
from .._project._build import Project
from .._statistics._adjustment import Adjustment
from .._statistics._summary import variance_test
from ._board_warp import BoardWarp, board_warp
from ._collect import (
    FIXED,
    camera_tables,
    datum_text,
    group_statistics,
    image_table,
    is_measurement,
    observation_ids,
    point_table,
    project_ids,
    rejections,
    reliability_summary,
)
from ._rigs import frame_table, mount_table, rig_baselines
from ._summaries import group_summaries, image_residual_summaries

MAX_POINT_ROWS = 1000  # rows of the points table; all of them are in results.json and NAME.sigma
LARGEST_RESIDUALS = 20  # rows of the table of the largest normalised residuals
FIGURE_DPI = 100

_STYLE = """
body { font-family: sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
h1 { border-bottom: 2px solid #446; } h2 { border-bottom: 1px solid #aab; margin-top: 2em; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.85em; }
th, td { border: 1px solid #ccd; padding: 2px 8px; text-align: right; }
th { background: #eef; } td.id, th.id { text-align: left; }
tr.outlier td { background: #fdd; } .fixed { color: #888; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #ddd; }
nav li { display: inline; margin-right: 1em; } p.note { color: #555; font-size: 0.85em; }
"""


def png_bytes(figure) -> bytes:
    """A matplotlib Figure as PNG at `FIGURE_DPI`."""
    image = io.BytesIO()
    figure.savefig(image, dpi=FIGURE_DPI, format="png")
    return image.getvalue()


def html_report(
    project: Project, result: Adjustment, *, figures: dict[str, bytes] | None = None,
    uncertainty: dict[str, bytes] | None = None,
) -> str:
    """The report page (UTF-8 text): summary, cameras, images, points (the first
    `MAX_POINT_ROWS`), observation groups, the largest normalised residuals, data-snooping
    rejections and the figures of `figure_set`, embedded as PNG.

    `figures`: PNG bytes by figure name, already drawn (e.g. for `--plots`); None draws them.
    `uncertainty`: the files of `uncertainty_files` by name (CSV text, PNG bytes): a section
    on the projection uncertainty of each camera with its maps; None leaves it out.
    """
    from ._plots._set import figure_set

    shown = figure_set(project, result)
    if figures is None:
        figures = {figure.name: png_bytes(figure.make()) for figure in shown}
    warp = board_warp(project, result)
    sections = [
        ("summary", "Summary", _summary(project, result)),
        ("cameras", "Cameras", _cameras(project, result)),
        *([("warp", "Board warp", _board_warp(warp))] if warp is not None else []),
        *([("rigs", "Rigs", _rigs(project, result))] if project.rigs is not None else []),
        ("images", "Images", _images(project, result)),
        ("points", "Object points", _points(project, result)),
        ("groups", "Observation groups", _groups(project, result)),
        ("residuals", "Largest normalised residuals", _largest(project, result)),
        ("figures", "Figures", _figures(shown, figures)),
    ]
    if uncertainty:
        sections.insert(-1, ("uncertainty", "Projection uncertainty", _uncertainty(uncertainty)))
    name = html.escape(project.spec.name)
    nav = "".join(f'<li><a href="#{key}">{title}</a></li>' for key, title, _ in sections)
    body = "\n".join(f'<section id="{key}">\n<h2>{title}</h2>\n{content}\n</section>'
                     for key, title, content in sections)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        f"<title>jaxba report: {name}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n"
        f"<h1>Bundle adjustment of {name}</h1>\n<nav><ul>{nav}</ul></nav>\n{body}\n"
        "</body>\n</html>\n"
    )


# --- formatting -----------------------------------------------------------------------------


def _decimals(sigma: float) -> int | None:
    """Decimals that show the second significant digit of `sigma` (None: σ 0 or unknown)."""
    if not (math.isfinite(sigma) and sigma > 0):
        return None
    return max(0, 1 - math.floor(math.log10(sigma)))


def _value(value: float, sigma: float) -> str:
    digits = _decimals(sigma)
    return f"{value:.{digits}f}" if digits is not None else f"{value:.8g}"


def _sigma(sigma: float) -> str:
    return f"{sigma:.2g}" if math.isfinite(sigma) and sigma > 0 else "-"


def _table(header: list[str], rows: list[list[str]], *, ids: int = 1,
           classes: list[str] | None = None) -> str:
    """An HTML table; the first `ids` columns left-aligned (class "id"), cells already
    escaped; `classes`: a class for each row ("" none)."""
    def cells(tag: str, row: list[str]) -> str:
        return "".join(f'<{tag} class="id">{cell}</{tag}>' if k < ids else f"<{tag}>{cell}</{tag}>"
                       for k, cell in enumerate(row))

    classes = classes or [""] * len(rows)
    body = "".join(
        (f'<tr class="{kind}">' if kind else "<tr>") + cells("td", row) + "</tr>\n"
        for kind, row in zip(classes, rows))
    return f"<table>\n<tr>{cells('th', header)}</tr>\n{body}</table>"


def _e(text) -> str:
    return html.escape(str(text))


# --- sections -------------------------------------------------------------------------------


def _summary(project: Project, result: Adjustment) -> str:
    precision = result.precision
    sigma0 = math.sqrt(precision.sigma0_squared)
    rows = [
        ["status", _e("converged" if result.converged else "not converged: " + result.message)],
        ["iterations", f'<span id="iterations">{result.n_iterations}</span>'],
        ["backend", _e(result.backend)],
        ["images / points", f"{len(project.image_ids)} / {len(project.point_ids)}"],
        ["observations", str(precision.n_observations)],
        ["unknowns", str(precision.n_unknowns)],
        ["redundancy", str(precision.redundancy)],
        ["σ0 a priori", f"{project.spec.settings.sigma0:.6g}"],
        ["σ̂0 a posteriori", f'<span id="sigma0">{sigma0:.6g}</span>'],
    ]
    test = variance_test(result)
    rows += [
        ["χ² test of σ̂0", '<span id="variance-test">'
         + _e(test.text() if test is not None else "not available") + "</span>"],
        ["datum", f'<span id="datum">{_e(datum_text(project, result))}</span>'],
    ]
    summary = image_residual_summaries(project, result)["all"]
    for unit, key in (("µm", "mm"), ("px", "px")):
        x, y = summary[f"rms_x_{key}"], summary[f"rms_y_{key}"]
        if math.isfinite(x) and math.isfinite(y):
            scale = 1000.0 if key == "mm" else 1.0
            rows.append([f"image residual RMS x / y ({unit})",
                         f"{scale * x:.3g} / {scale * y:.3g}"])
    reliability = reliability_summary(project, result)
    if reliability is not None:
        rows += [
            ["critical |w| (α)", f"{reliability.critical_value:.3f} ({reliability.alpha:g})"],
            ["largest |w|", f"{reliability.max_abs_w:.3f} at {_e(reliability.max_abs_w_at)}"],
            ["outliers (|w| above critical)", str(reliability.n_outliers)],
        ]
    rows.append(["data-snooping rejections", str(len(result.rejections))])
    return _table(["quantity", "value"], rows, ids=1)


def _cameras(project: Project, result: Adjustment) -> str:
    parts = []
    for cid, table in camera_tables(project, result).items():
        rows, classes = [], []
        for k, name in enumerate(table.names):
            value, std, status = table.values[0, k], table.stds[0, k], table.status[0][k]
            rows.append([_e(name), _value(value, std), _sigma(std), _e(status)])
            classes.append("fixed" if status == FIXED else "")
        model = project.camera_rows[cid][0]
        parts.append(f"<h3>Camera {_e(cid)} ({_e(model)})</h3>\n"
                     + _table(["parameter", "value", "σ", "status"], rows, classes=classes))
    return "\n".join(parts)


def _parameter_rows(table, extra=None) -> list[list[str]]:
    rows = []
    for k, rid in enumerate(table.ids):
        cells = [_e(rid)] + (extra[k] if extra else [])
        for j in range(len(table.names)):
            cells.append(_value(table.values[k, j], table.stds[k, j]))
        cells += [_sigma(table.stds[k, j]) for j in range(len(table.names))]
        rows.append(cells)
    return rows


def _images(project: Project, result: Adjustment) -> str:
    table = image_table(project, result)
    per_image = image_residual_summaries(project, result)["images"]
    extra = []
    for iid in table.ids:
        entry = per_image.get(iid)
        pixel = entry is not None and math.isfinite(entry["rms_x_px"])
        rms = (f"{entry['rms_x_px']:.2f} / {entry['rms_y_px']:.2f}" if pixel else "-")
        extra.append([_e(project.spec.images[iid].camera),
                      str(entry["n"]) if entry else "0", rms])
    names = [*table.names]
    header = (["image", "camera", "points", "RMS x / y (px)"] + names
              + [f"σ {name}" for name in names])
    return ("<p class=\"note\">Angles in degrees; σ 0 (\"-\"): fixed.</p>\n"
            + _table(header, _parameter_rows(table, extra), ids=2))


def _rigs(project: Project, result: Adjustment) -> str:
    """Every rig camera's (and platform camera's) pose in its rig with its baseline, and
    every frame's pose."""
    mounts, baselines = mount_table(project, result), rig_baselines(project, result)
    extra = [[f"{_value(baselines[mid][0], baselines[mid][1])} ± {_sigma(baselines[mid][1])}"]
             for mid in mounts.ids]
    names = [*mounts.names]
    header = ["camera", "baseline"] + names + [f"σ {name}" for name in names]
    frames = frame_table(project, result)
    return ("<p class=\"note\">Each camera's pose in its rig's frame (the reference camera's;"
            " rotation rig → camera, degrees) and its baseline, the distance from the"
            " reference camera, object units.</p>\n"
            + _table(header, _parameter_rows(mounts, extra), ids=2)
            + "\n<h3>Frames</h3>\n"
            + _table(["frame"] + names + [f"σ {name}" for name in names],
                     _parameter_rows(frames, [[] for _ in frames.ids])))


def _board_warp(warp: BoardWarp) -> str:
    """kx, ky of every board with σ and ρ(kx, ky), and their correlations with every camera's
    estimated IOPs."""
    rows = [[_e(board), *(_value(warp.values[b, k], warp.stds[b, k]) for k in range(2)),
             *(_sigma(warp.stds[b, k]) for k in range(2)), f"{warp.rho[b]:.2f}"]
            for b, board in enumerate(warp.ids)]
    parts = ["<p class=\"note\">Each board point moved along the board's normal by"
             " kx (1 − x²) + ky (1 − y²), x, y from −1 to 1 over the board; object units.</p>",
             _table(["board", "kx", "ky", "σ kx", "σ ky", "ρ(kx, ky)"], rows)]
    for cid, (names, rho) in warp.cameras.items():
        if names:
            parts.append(f"<h3>Correlations with the IOPs of camera {_e(cid)}</h3>\n" + _table(
                ["", *map(_e, names)],
                [[f"{_e(board)} {name}", *(f"{r:.2f}" for r in rho[b, k])]
                 for b, board in enumerate(warp.ids) for k, name in enumerate(("kx", "ky"))]))
    return "\n".join(parts)


def _points(project: Project, result: Adjustment) -> str:
    table = point_table(project, result)
    n = len(table.ids)
    shown = table if n <= MAX_POINT_ROWS else type(table)(
        table.names, table.ids[:MAX_POINT_ROWS], table.values[:MAX_POINT_ROWS],
        table.stds[:MAX_POINT_ROWS], table.status[:MAX_POINT_ROWS])
    note = (f"<p class=\"note\">The first {MAX_POINT_ROWS} of {n} points; all of them are in"
            " results.json and the .sigma report.</p>\n" if n > MAX_POINT_ROWS else "")
    names = [*table.names]
    return note + _table(["point"] + names + [f"σ {name}" for name in names],
                         _parameter_rows(shown))


def _groups(project: Project, result: Adjustment) -> str:
    rows = [[_e(name), str(entry["n"]), f"{entry['vtpv']:.6g}"]
            for name, entry in group_summaries(project, result).items()]
    return _table(["group", "observations", "vᵀPv"], rows)


def _largest(project: Project, result: Adjustment) -> str:
    """The observations with the largest |w| (or |v / σ| without reliability), rejections
    included, and the data-snooping rejections in order."""
    entries = []
    for stats in group_statistics(project, result):
        if not is_measurement(stats.group):
            continue
        size = np.abs(stats.w) if result.reliability is not None else np.abs(
            stats.v / np.asarray(stats.group.sigma(), dtype=float))
        size = np.where(stats.observed & np.isfinite(size), size, -1.0)
        for flat in np.argsort(-size, axis=None)[:LARGEST_RESIDUALS]:
            row, coordinate = np.unravel_index(flat, size.shape)
            if size[row, coordinate] >= 0:
                entries.append((float(size[row, coordinate]), stats, int(row), int(coordinate)))
    entries.sort(key=lambda entry: -entry[0])
    rows, classes = [], []
    for _, stats, row, coordinate in entries[:LARGEST_RESIDUALS]:
        ids = observation_ids(project, stats.group, row, coordinate)
        rows.append([
            _e(part_name(stats.group, project_ids(project).cameras, row)),
            _e(" ".join(f"{k} {v}" for k, v in ids.items())),
            f"{stats.v[row, coordinate]:.4g}", f"{stats.w[row, coordinate]:.3f}",
            f"{stats.r[row, coordinate]:.3f}",
            "rejected" if stats.removed[row, coordinate] else (
                "outlier" if stats.outlier[row, coordinate] else ""),
        ])
        classes.append("outlier" if stats.outlier[row, coordinate] else "")
    header = ["group", "observation", "v", "w", "r", "flag"]
    text = _table(header, rows, ids=2, classes=classes)
    found = rejections(project, result)
    if found:
        text += "\n<h3>Data-snooping rejections, in order of removal</h3>\n" + _table(
            ["group", "observation", "|w|"],
            [[_e(entry["group"]),
              _e(" ".join(f"{k} {v}" for k, v in entry.items() if k not in ("group", "w"))),
              f"{entry['w']:.2f}"] for entry in found], ids=2)
    note = ("<p class=\"note\">v = observed - computed in the observation's units (image"
            " points: mm, or pixels for pixel models); w the normalised residual, r the"
            " redundancy number.</p>\n")
    return note + text


def _uncertainty(files: dict[str, str | bytes]) -> str:
    """Per camera σ in the worst direction at the sensor's centre, its median and largest
    over the grid (uncertainty_<camera>.csv), and the two figures."""
    rows, images = [], []
    for name, content in files.items():
        if name.endswith(".csv"):
            table = np.loadtxt(io.StringIO(content), delimiter=",", skiprows=1, ndmin=2)
            centre = table[:, :2].mean(axis=0)
            near = np.argmin(np.linalg.norm(table[:, :2] - centre, axis=1))
            worst = table[:, 2]
            rows.append([_e(name.removeprefix("uncertainty_").removesuffix(".csv")),
                         f"{worst[near]:.3g}", f"{np.median(worst):.3g}",
                         f"{worst.max():.3g}"])
        elif name.endswith(".png"):
            data = base64.b64encode(content).decode("ascii")
            images.append(f'<figure><img alt="{_e(name)}" src="data:image/png;base64,{data}">'
                          f"<figcaption>{_e(name)}</figcaption></figure>")
    header = ["camera", "σ worst at the centre (px)", "median (px)", "largest (px)"]
    return _table(header, rows) + "\n" + "\n".join(images)


def _figures(shown, figures: dict[str, bytes]) -> str:
    parts = []
    for figure in shown:
        data = base64.b64encode(figures[figure.name]).decode("ascii")
        parts.append(
            f'<figure id="figure-{_e(figure.name)}"><img alt="{_e(figure.title)}"'
            f' src="data:image/png;base64,{data}"><figcaption>{_e(figure.title)}'
            "</figcaption></figure>")
    return "\n".join(parts)

