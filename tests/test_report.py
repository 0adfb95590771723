"""Tests of the report writers on a hand-made adjustment result (no solve: fast).

The result holds the lab project's approximations, known standard deviations and seeded
random residuals, so every number in the reports can be recomputed independently here.
"""

import json
import math
import pathlib
import shutil

import numpy as np
import pytest

import jaxba
from jaxba._parameters import Parameters
from jaxba._report import (
    OutputError,
    out_text,
    res_text,
    results_dict,
    results_json,
    sigma_text,
    write_reports,
)
from jaxba._statistics import Precision

LAB = pathlib.Path(__file__).resolve().parents[1] / "configs" / "lab"
PIXEL = 0.00369  # mm, the lab camera's pixel size
STD_MM = 1e-3  # σ given to every free IOP in the fake result
STD_RAD = 1e-4  # σ given to every free EOP angle, radians
STD_OBJ = 2e-4  # σ given to every free position and point coordinate, object units
PRINTED_MM = 5e-7  # half a unit in the last decimal (6) of mm values in .res
PRINTED_PX = 5e-4  # half a unit in the last decimal (3) of pixel values in .res
FILES = ("lab.out", "lab.res", "lab.sigma", "results.json")


def _copy_lab(tmp_path: pathlib.Path) -> pathlib.Path:
    folder = tmp_path / "lab"
    shutil.copytree(LAB, folder, ignore=shutil.ignore_patterns(*FILES))
    return folder


def _edit(path: pathlib.Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, f"{old!r} not in {path}"
    path.write_text(text.replace(old, new, 1))


def _fake_result(project, *, nan_std: bool = False, seed: int = 0) -> jaxba.Adjustment:
    """The approximations as 'adjusted' values with known σ and random residuals."""
    problem = project.problem
    free = problem.free
    std = Parameters(
        cameras={m: np.where(np.asarray(f), STD_MM, 0.0) for m, f in free.cameras.items()},
        images=np.where(np.asarray(free.images), [STD_OBJ] * 3 + [STD_RAD] * 3, 0.0),
        points=np.where(np.asarray(free.points), STD_OBJ, 0.0),
    )
    if nan_std:
        std.points[0, 0] = math.nan
    rng = np.random.default_rng(seed)
    residuals = tuple(
        rng.normal(0.0, 1e-3, np.shape(group.sigma())) * np.asarray(group.mask())
        for group in problem.groups
    )
    n, u = problem.n_observations(), problem.n_unknowns()
    iterations = [jaxba.Iteration(0, 50.0 * (n - u), 100.0), jaxba.Iteration(1, 0.5 * (n - u), 1.0)]
    precision = Precision(
        sigma0_squared=1.0, redundancy=n - u, n_observations=n, n_unknowns=u,
        free_index=np.zeros(0, dtype=int), covariance=np.zeros((0, 0)), std=std,
    )
    return jaxba.Adjustment(
        problem=problem, parameters=problem.initial, precision=precision, residuals=residuals,
        iterations=iterations, converged=True, message="converged", steps=2,
    )


def _data_lines(text: str) -> list[list[str]]:
    return [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]


@pytest.fixture
def lab(tmp_path):
    folder = _copy_lab(tmp_path)
    project = jaxba.build_project(jaxba.read_project(folder / "lab.toml"))
    return project, _fake_result(project)


def test_json_degrees_status_and_fixed_std(lab):
    project, result = lab
    data = results_dict(project, result)
    approximations = project.spec.images
    for iid, entry in data["images"].items():
        for k, name in enumerate(jaxba.IMAGE_PARAMETER_NAMES):
            assert entry[name]["value"] == pytest.approx(approximations[iid].eop[k], abs=1e-9)
        assert entry["omega"]["std"] == pytest.approx(math.degrees(STD_RAD), rel=1e-12)
        assert entry["X0"]["std"] == pytest.approx(STD_OBJ, rel=1e-12)
    camera = data["cameras"]["C1"]
    assert list(camera) == list(jaxba.CAMERA_MODELS["smac"].parameter_names)
    assert camera["K0"] == {"value": 0.0, "std": 0.0, "status": "fixed"}
    assert camera["c"]["status"] == "free" and camera["c"]["std"] == STD_MM
    fixed_point = next(
        pid for pid, spec in project.spec.points.items() if spec.sigma == (0.0, 0.0, 0.0)
    )
    assert {e["status"] for e in data["points"][fixed_point].values()} == {"fixed"}
    assert all(e["std"] == 0.0 for e in data["points"][fixed_point].values())
    assert data["sigma0"] == pytest.approx(math.sqrt(data["sigma0_squared"]))
    assert data["iterations"][1] == {
        "iteration": 1, "sigma0_squared": 1.0, "cost": result.iterations[1].cost,
    }


def test_json_strict_with_nan(lab):
    project, _ = lab
    result = _fake_result(project, nan_std=True)
    data = json.loads(results_json(project, result))  # the text parses as strict JSON
    assert data["points"][project.point_ids[0]]["X"]["std"] is None
    assert "NaN" not in results_json(project, result)


def test_res_rows_and_rms(lab):
    project, result = lab
    rows = _data_lines(res_text(project, result))
    assert len(rows) == len(project.spec.image_points)
    v = np.concatenate([r for r in result.residuals if r.shape[1] == 2])
    assert len(rows) == len(v)
    vx_vy = np.array([[float(x) for x in row[4:6]] for row in rows])
    v_px = np.array([[float(x) for x in row[6:8]] for row in rows])
    np.testing.assert_allclose(v_px, vx_vy / PIXEL, atol=PRINTED_MM / PIXEL + PRINTED_PX)
    # Rows are sorted by image, in the order of the images table.
    image_order = {iid: k for k, iid in enumerate(project.image_ids)}
    assert [image_order[row[0]] for row in rows] == sorted(image_order[row[0]] for row in rows)
    # Same multiset of residuals as the result (the sort only permutes rows).
    np.testing.assert_allclose(np.sort(vx_vy, axis=0), np.sort(v, axis=0), atol=PRINTED_MM)
    lines = res_text(project, result).splitlines()
    words = next(line for line in lines if line.startswith("# RMS all")).split()
    assert float(words[words.index("vx") + 1]) == pytest.approx(
        math.sqrt(np.mean(v[:, 0] ** 2)), abs=PRINTED_MM
    )
    data = results_dict(project, result)["image_residuals"]["all"]
    assert data["n"] == len(v)
    assert data["rms_y_px"] == pytest.approx(math.sqrt(np.mean(v[:, 1] ** 2)) / PIXEL, rel=1e-12)


def test_sigma_file(lab):
    project, result = lab
    rows = _data_lines(sigma_text(project, result))
    assert [int(r[0]) for r in rows] == [it.iteration for it in result.iterations]
    for row, it in zip(rows, result.iterations):
        assert float(row[1]) == pytest.approx(it.sigma0_squared, rel=1e-10)
        assert float(row[2]) == pytest.approx(it.cost, rel=1e-10)


def test_out_sections(lab):
    project, result = lab
    text = out_text(project, result)
    for heading in ("Camera C1", "Exterior orientation", "Object points", "redundancy"):
        assert heading in text
    eop_lines = [line.split() for line in text.splitlines() if line.strip().startswith("img")]
    assert len(eop_lines) == len(project.image_ids)
    omega = project.spec.images[eop_lines[0][0]].eop[3]
    assert float(eop_lines[0][5]) == pytest.approx(omega, abs=1e-3)  # degrees, not radians


def test_weighted_camera_parameter_and_no_pixel_size(tmp_path):
    folder = _copy_lab(tmp_path)
    cameras = folder / "cameras.toml"
    _edit(cameras, "pixel_size = [0.00369, 0.00369]\n", "")
    _edit(cameras, "sensor = [6000, 4000]\n", "")
    cameras.write_text(cameras.read_text() + "[C1.sigma]\nP3 = 1e-6\n")
    project = jaxba.build_project(jaxba.read_project(folder / "lab.toml"))
    result = _fake_result(project)
    data = json.loads(results_json(project, result))
    assert data["cameras"]["C1"]["P3"]["status"] == "weighted"
    assert data["image_residuals"]["all"]["rms_x_px"] is None
    rows = _data_lines(res_text(project, result))
    assert {row[6] for row in rows} == {"-"}


def test_write_reports_creates_folder(lab, tmp_path):
    project, result = lab
    out = tmp_path / "new" / "reports"
    written = write_reports(project, result, out)
    assert sorted(p.name for p in written) == sorted(FILES)
    assert all(p.parent == out and p.is_file() for p in written)


def test_refuses_to_overwrite_an_input(tmp_path):
    folder = _copy_lab(tmp_path)
    (folder / "distances.txt").rename(folder / "lab.sigma")
    _edit(folder / "lab.toml", '"distances.txt"', '"lab.sigma"')
    project = jaxba.build_project(jaxba.read_project(folder / "lab.toml"))
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    with pytest.raises(OutputError, match="lab.sigma"):
        write_reports(project, _fake_result(project), folder)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
