"""Tests of the report writers on a hand-made adjustment result (no solve: fast).

The result holds the lab project's approximations, known standard deviations, a seeded
random covariance and seeded random residuals (and, where a test asks, hand-made
reliability, variance components and a data-snooping rejection), so every number in the
reports can be recomputed independently here.
"""

import dataclasses
import json
import math
import pathlib
import re
import shutil

import equinox as eqx
import numpy as np
import pytest
import scipy.stats
from board_scene import write_project

import jaxba
from jaxba._files import OutputError
from jaxba._problem._bundle import free_indices
from jaxba._problem._parameters import Parameters, flatten, unflatten
from jaxba._report import (
    observations_csv,
    out_text,
    res_text,
    results_dict,
    results_json,
    sigma_text,
    summary_lines,
    warning_lines,
    write_reports,
)
from jaxba._statistics._covariance import Precision

CONFIGS = pathlib.Path(__file__).resolve().parents[1] / "configs"
LAB = CONFIGS / "lab"
PIXEL = 0.00369  # mm, the lab camera's pixel size
STD_MM = 1e-3  # σ given to every free IOP in the fake result
STD_RAD = 1e-4  # σ given to every free EOP angle, radians
STD_OBJ = 2e-4  # σ given to every free position and point coordinate, object units
PRINTED_MM = 5e-7  # half a unit in the last decimal (6) of mm values in .res
PRINTED_PX = 5e-4  # half a unit in the last decimal (3) of pixel values in .res
FILES = ("lab.out", "lab.res", "lab.sigma", "results.json", "observations.csv")
MATRIX_RTOL = 1e-12  # correlations and ellipsoids against NumPy on the same covariance
PRINTED_W = 5e-3  # half a unit in the last decimal (2) of w in .res
CRITICAL = 3.29  # critical |w| of the hand-made reliability
CSV_RTOL = 1e-9  # observations.csv writes numbers with 10 significant digits


def _copy_lab(tmp_path: pathlib.Path) -> pathlib.Path:
    folder = tmp_path / "lab"
    shutil.copytree(LAB, folder, ignore=shutil.ignore_patterns(*FILES))
    return folder


def _edit(path: pathlib.Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, f"{old!r} not in {path}"
    path.write_text(text.replace(old, new, 1))


def _fake_result(project, *, nan_std: bool = False, seed: int = 0) -> jaxba.Adjustment:
    """The approximations as 'adjusted' values with known σ, a random SPD covariance of the
    free unknowns and random residuals."""
    problem = project.problem
    free = problem.free
    std = Parameters(
        cameras={m: np.where(np.asarray(f), STD_MM, 0.0) for m, f in free.cameras.items()},
        images=np.where(np.asarray(free.images), [STD_OBJ] * 3 + [STD_RAD] * 3, 0.0),
        points=np.where(np.asarray(free.points), STD_OBJ, 0.0),
        warp=None if free.warp is None else np.where(np.asarray(free.warp), STD_OBJ, 0.0),
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
    factor = rng.normal(0.0, 1e-4, (u, u + 5))
    precision = Precision(
        sigma0_squared=1.0, redundancy=n - u, n_observations=n, n_unknowns=u,
        free_index=free_indices(problem), covariance=factor @ factor.T, std=std,
    )
    return jaxba.Adjustment(
        problem=problem, parameters=problem.initial, precision=precision, residuals=residuals,
        iterations=iterations, converged=True, message="converged", steps=2,
    )


def _with_statistics(project, result, *, removed_row: int = 5, seed: int = 1):
    """`result` with a hand-made reliability, variance components and one image point of the
    first group removed by 'data snooping' (σ = inf, listed in `rejections`); w of one other
    observation (row 0, y) is set above the critical value."""
    problem = jaxba.remove_observation(result.problem, 0, removed_row, 0)
    rng = np.random.default_rng(seed)
    masks = [np.asarray(group.mask()) for group in problem.groups]
    r = tuple(np.where(m, rng.uniform(0.2, 0.9, m.shape), np.nan) for m in masks)
    w = [np.where(m, rng.normal(0.0, 1.0, m.shape).clip(-3, 3), np.nan) for m in masks]
    w[0][0, 1] = 4.5
    residuals = list(result.residuals)
    residuals[0] = np.where(masks[0], residuals[0], 0.0)
    reliability = jaxba.Reliability(
        redundancy_numbers=r, normalised_residuals=tuple(w), mdb=r, alpha=0.001,
        critical_value=CRITICAL,
    )
    # Keyed as `estimate_variance_components` keys them: the image points per camera.
    components = {
        ("image_points:C1" if k == 0 else group.name):
            jaxba.VarianceComponent(1.0 + 0.1 * k, 10.0 * k + 1.5, int(m.sum()))
        for k, (group, m) in enumerate(zip(problem.groups, masks))
    }
    rejection = jaxba.Rejection(problem.groups[0].name, removed_row, 0, 7.5)
    return dataclasses.replace(
        result, problem=problem, residuals=tuple(residuals), reliability=reliability,
        variance_components=components, variance_iterations=3, rejections=(rejection,),
    )


def _observations(project, result, tmp_path: pathlib.Path) -> dict[str, np.ndarray]:
    """observations.csv of `result`, read back with `jaxba.read_observations`."""
    path = tmp_path / "observations.csv"
    path.write_text(observations_csv(project, result))
    return jaxba.read_observations(path)


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


@pytest.mark.parametrize("nan_std", [False, True])
def test_json_points_text_is_the_points_tree(lab, nan_std):
    """results.json's points, laid out in one pass with orjson's numbers, read back to the
    very tree `results_dict` builds: every value, σ, status and ellipsoid, null for NaN."""
    project, result = lab
    result = _fake_result(project, nan_std=True) if nan_std else result
    points = results_dict(project, result)["points"]
    assert any("ellipsoid" in entry for entry in points.values())
    assert any(entry["X"]["std"] is None for entry in points.values()) == nan_std
    assert json.loads(results_json(project, result))["points"] == points


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


@pytest.mark.parametrize("name", ["lab.sigma", "observations.csv"])
def test_refuses_to_overwrite_an_input(tmp_path, name):
    folder = _copy_lab(tmp_path)
    (folder / "distances.txt").rename(folder / name)
    _edit(folder / "lab.toml", '"distances.txt"', f'"{name}"')
    project = jaxba.build_project(jaxba.read_project(folder / "lab.toml"))
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    with pytest.raises(OutputError, match=name):
        write_reports(project, _fake_result(project), folder)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_reports_are_replaced(lab, tmp_path):
    """A second write replaces every report, observations.csv included."""
    project, result = lab
    write_reports(project, _fake_result(project, seed=1), tmp_path / "out")
    write_reports(project, result, tmp_path / "out")
    table = jaxba.read_observations(tmp_path / "out" / "observations.csv")
    k = len(result.problem.groups) - 1
    np.testing.assert_allclose(table["v"][table["type"] == "distances"],
                               result.residuals[k][:, 0], rtol=CSV_RTOL)
    texts = {
        "lab.out": out_text, "lab.res": res_text, "lab.sigma": sigma_text,
        "results.json": results_json,
    }
    for name, text in texts.items():
        assert (tmp_path / "out" / name).read_text() == text(project, result), name


def test_json_correlations_and_ellipsoids(lab):
    project, result = lab
    data = results_dict(project, result)
    covariance = np.zeros((flatten(result.parameters).size,) * 2)
    index = result.precision.free_index
    covariance[np.ix_(index, index)] = result.precision.covariance
    position = unflatten(result.parameters, np.arange(covariance.shape[0]))
    # Correlations of the estimated IOPs, in the model's parameter order.
    free_names = ["xp", "yp", "c", "K1", "K2", "K3", "P1", "P2"]
    entry = data["correlations"]["C1"]
    assert entry["parameters"] == free_names
    names = jaxba.CAMERA_MODELS["smac"].parameter_names
    chosen = [int(position.cameras["smac"][0][names.index(n)]) for n in free_names]
    block = covariance[np.ix_(chosen, chosen)]
    expected = block / np.sqrt(np.outer(np.diag(block), np.diag(block)))
    np.testing.assert_allclose(entry["matrix"], expected, rtol=MATRIX_RTOL, atol=1e-15)
    # 1σ ellipsoids: axes² are the eigenvalues of the point's 3x3 block, axes along columns.
    free_points = np.asarray(project.problem.free.points).any(axis=1)
    for k, pid in enumerate(project.point_ids):
        if not free_points[k]:
            assert "ellipsoid" not in data["points"][pid]
            continue
        rows = np.asarray(position.points[k])
        c = covariance[np.ix_(rows, rows)]
        ellipsoid = data["points"][pid]["ellipsoid"]
        axes, directions = np.array(ellipsoid["axes"]), np.array(ellipsoid["directions"])
        np.testing.assert_allclose(axes**2, np.sort(np.linalg.eigvalsh(c))[::-1], rtol=1e-10)
        for a, d in zip(axes, directions):
            np.testing.assert_allclose(c @ d, a**2 * d, atol=1e-10 * a**2 + 1e-30)
    assert list(data["points"][project.point_ids[-1]])[:3] == list(jaxba.POINT_PARAMETER_NAMES)


def test_json_without_statistics(lab, tmp_path):
    """No reliability, components or rejections in the result: null / empty, no outliers."""
    project, result = lab
    data = json.loads(results_json(project, result))
    assert data["variance_components"] is None
    assert data["variance_component_iterations"] is None
    assert data["reliability"] is None and data["rejections"] == []
    assert data["observations_file"] == "observations.csv" and "observations" not in data
    table = _observations(project, result, tmp_path)
    image = table["type"] == "image_points"
    assert list(table) == [
        "type", "group", "image", "point", "point_b", "camera", "coordinate", "x", "y", "vx",
        "vy", "rx", "ry", "wx", "wy", "v", "r", "w", "removed", "outlier",
    ]
    assert np.count_nonzero(image) == len(project.spec.image_points)
    assert set(table["group"][image]) == {"image_points:C1"}
    assert set(table["camera"][image]) == {"C1"}
    for name in ("rx", "ry", "wx", "wy", "v", "r", "w"):
        assert np.all(np.isnan(table[name][image])), name
    assert not table["outlier"].any() and not table["removed"].any()
    assert set(table["point_b"][image]) == set(table["coordinate"][image]) == {""}
    assert np.count_nonzero(~image) == len(project.spec.distances)
    distances = {(d.a, d.b) for d in project.spec.distances}
    assert set(zip(table["point"][~image], table["point_b"][~image])) == distances
    assert set(table["type"][~image]) == {"distances"}
    assert np.all(np.isnan(table["vx"][~image])) and np.all(np.isfinite(table["v"][~image]))
    assert data["units"]["image"] == "mm" and data["units"]["image_cameras"] == {"C1": "mm"}


def test_observation_table_rows(lab, tmp_path):
    """observations.csv rows equal the result's residuals, measurements and IDs (%.10g)."""
    project, result = lab
    table = _observations(project, result, tmp_path)
    image = table["type"] == "image_points"
    group = result.problem.groups[0]
    assert np.count_nonzero(image) == len(group.measured) == len(project.spec.image_points)
    # Rows of the one image-point group, sorted by image (stable: file order within one).
    order = np.argsort(np.asarray(group.image), kind="stable")
    ids = [(project.image_ids[int(group.image[k])], project.point_ids[int(group.point[k])])
           for k in order]
    assert list(zip(table["image"][image], table["point"][image])) == ids
    xy = np.column_stack([table["x"][image], table["y"][image]])
    v = np.column_stack([table["vx"][image], table["vy"][image]])
    np.testing.assert_allclose(xy, np.asarray(group.measured)[order], rtol=CSV_RTOL)
    np.testing.assert_allclose(v, np.asarray(result.residuals[0])[order], rtol=CSV_RTOL)
    k = len(result.problem.groups) - 1
    np.testing.assert_allclose(table["v"][~image], result.residuals[k][:, 0], rtol=CSV_RTOL)


def test_observation_table_other_types(tmp_path):
    """Control, GNSS/INS and camera-prior rows: their IDs, coordinates and v (GNSS/INS angles
    in degrees), one row per observed coordinate, group by group."""
    folder = tmp_path / "block"
    jaxba.write_synthetic_project(folder, n_images=6, n_targets=20, gnss_sigma=(0.01, 0.1))
    _edit(folder / "ground_points.txt", " - - -", " 0.001 0.002 0.003")  # control point
    cameras = folder / "cameras.toml"
    cameras.write_text(cameras.read_text() + "[C1.sigma]\nP3 = 1e-6\n")
    project = jaxba.build_project(jaxba.read_project(folder / "lab.toml"))
    result = _fake_result(project)
    table = _observations(project, result, tmp_path)
    kinds = {"control", "gnss_ins", "camera_priors", "distances"}
    assert set(table["type"]) == {"image_points"} | kinds
    groups = {group.name: k for k, group in enumerate(result.problem.groups)}
    expected = {
        "control": ("point", "XYZ"), "gnss_ins": ("image", jaxba.IMAGE_PARAMETER_NAMES),
        "camera_priors": ("camera", jaxba.CAMERA_MODELS["smac"].parameter_names),
    }
    for kind, (key, names) in expected.items():
        chosen = table["type"] == kind
        (name,) = set(table["group"][chosen])
        group = result.problem.groups[groups[name]]
        rows, coordinates = np.nonzero(np.asarray(group.mask()))
        assert table["coordinate"][chosen].tolist() == [names[c] for c in coordinates], kind
        v = np.asarray(result.residuals[groups[name]])[rows, coordinates]
        if kind == "gnss_ins":
            v = np.where(coordinates >= 3, np.degrees(v), v)
        np.testing.assert_allclose(table["v"][chosen], v, rtol=CSV_RTOL, err_msg=kind)
        assert np.all(table[key][chosen] != "") and np.all(np.isnan(table["vx"][chosen]))
    assert set(table["point"][table["type"] == "control"]) == {"2"}
    priors = table["type"] == "camera_priors"
    assert table["camera"][priors].tolist() == ["C1"] and table["coordinate"][priors] == ["P3"]
    gnss = table["type"] == "gnss_ins"
    assert table["image"][gnss].tolist() == [iid for iid in project.image_ids for _ in range(6)]


def test_statistics_in_json(lab, tmp_path):
    project, result = lab
    result = _with_statistics(project, result)
    data = json.loads(results_json(project, result))
    group = result.problem.groups[0]
    removed = (project.image_ids[int(group.image[5])], project.point_ids[int(group.point[5])])
    flagged = (project.image_ids[int(group.image[0])], project.point_ids[int(group.point[0])])
    assert data["rejections"] == [{
        "group": "image_points:C1", "image": removed[0], "point": removed[1],
        "coordinate": "x", "w": 7.5,
    }]
    assert data["variance_component_iterations"] == 3
    assert data["variance_components"]["image_points:C1"] == {
        "sigma0": 1.0, "redundancy": 1.5, "n_observations": group.measured.size - 2,
    }
    assert data["variance_components"]["distances"]["sigma0"] == pytest.approx(1.1)
    table = _observations(project, result, tmp_path)
    image = {
        (iid, pid): {name: table[name][k] for name in table}
        for k, (iid, pid) in enumerate(zip(table["image"], table["point"]))
        if table["type"][k] == "image_points"
    }
    # The removed point: its residual at the solution (observed - computed, σ = 1), no r,
    # w as rejected (with the sign of v), an outlier.
    entry = image[removed]
    unit = np.asarray(eqx.filter_jit(jaxba.advanced.collinearity_residual)(
        "smac", result.parameters.cameras["smac"][0],
        result.parameters.images[int(group.image[5])],
        result.parameters.points[int(group.point[5])], group.measured[5], np.ones(2),
        result.problem.refraction,
    ))
    assert [entry["vx"], entry["vy"]] == pytest.approx(unit.tolist(), rel=CSV_RTOL)
    assert math.isnan(entry["rx"]) and math.isnan(entry["ry"]) and math.isnan(entry["wy"])
    assert entry["wx"] == math.copysign(7.5, unit[0]) and entry["outlier"] and entry["removed"]
    # |w| above the critical value: an outlier too; everything else is not.
    assert image[flagged]["wy"] == 4.5 and image[flagged]["outlier"]
    assert not image[flagged]["removed"]
    assert sum(o["outlier"] for o in image.values()) == 2
    r0 = result.reliability.redundancy_numbers[0]
    assert image[flagged]["rx"] == pytest.approx(r0[0, 0], rel=CSV_RTOL)
    assert image[flagged]["ry"] == pytest.approx(r0[0, 1], rel=CSV_RTOL)
    reliability = data["reliability"]
    assert reliability["alpha"] == 0.001 and reliability["critical_value"] == CRITICAL
    total = sum(np.nansum(r) for r in result.reliability.redundancy_numbers)
    assert reliability["redundancy_sum"] == pytest.approx(total, rel=1e-12)
    distances = table["type"] == "distances"
    k = len(result.problem.groups) - 1
    np.testing.assert_allclose(
        table["r"][distances], result.reliability.redundancy_numbers[k][:, 0], rtol=CSV_RTOL)
    np.testing.assert_allclose(table["v"][distances], result.residuals[k][:, 0], rtol=CSV_RTOL)
    # RMS summaries leave the removed point out.
    assert data["image_residuals"]["all"]["n"] == len(project.spec.image_points) - 1
    assert data["image_residuals"]["all"]["n_removed"] == 1


def test_statistics_in_text_reports(lab):
    project, result = lab
    result = _with_statistics(project, result)
    text = out_text(project, result)
    for heading in (
        "IOP correlations of camera C1", "Variance components (3 iterations",
        "1 observation(s) rejected", "Reliability", "largest |w| 4.50",
        "Error ellipsoids of object points",
    ):
        assert heading in text, heading
    lines = res_text(project, result).splitlines()
    header = next(line for line in lines if "image_id" in line).split()[1:]
    assert header[-5:] == ["rx", "ry", "wx", "wy", "outlier"]
    rows = _data_lines(res_text(project, result))
    assert {len(row) for row in rows} == {13}
    outliers = [row for row in rows if row[-1] == "1"]
    assert len(outliers) == 2 and {row[-1] for row in rows} == {"0", "1"}
    removed = next(row for row in outliers if row[8] == "-")
    assert abs(float(removed[10])) == 7.5 and removed[11] == "-"
    w = np.array([[float(x) for x in row[10:12]] for row in rows if row[-1] == "0"])
    assert np.all(np.abs(w) <= CRITICAL + PRINTED_W)
    assert "1 rejected, not counted" in lines[-1]


def test_pixel_camera_model_reports(tmp_path):
    """An "opencv" camera works in pixels: reports say pixels, no mm or px-conversion columns."""
    project = jaxba.build_project(jaxba.read_project(CONFIGS / "zhang" / "zhang.toml"))
    result = _fake_result(project)
    data = results_dict(project, result)
    assert data["units"]["image"] == "pixel"
    summary = data["image_residuals"]["all"]
    v = np.concatenate([r for r in result.residuals if r.shape[1] == 2])
    assert summary["rms_x_mm"] is None
    assert summary["rms_x_px"] == pytest.approx(math.sqrt(np.mean(v[:, 0] ** 2)), rel=1e-12)
    assert data["correlations"]["C1"]["parameters"] == ["fx", "fy", "cx", "cy", "skew", "k1", "k2"]
    text = res_text(project, result)
    assert "in pixels" in text and "vx_px" not in text and " mm" not in text
    rows = _data_lines(text)
    assert {len(row) for row in rows} == {11}
    out = out_text(project, result)
    assert "pixel units" in out and "mm based" not in out and "rms_vx_mm" not in out
    # A fixed target: no point has a free coordinate, so no (empty) ellipsoid table.
    assert "Error ellipsoids" not in out and "Object points" in out


def test_datum_backend_variance_test_and_outliers_in_out_json_and_console(lab):
    """NAME.out, results.json and the console name the datum, the backend, the χ² test of the
    variance factor (here failed: σ̂0² = 1.5 at σ0 = 1) and the outliers (one |w| above the
    critical value, one rejection)."""
    project, result = lab
    result = _with_statistics(project, result)
    precision = dataclasses.replace(result.precision, sigma0_squared=1.5)
    result = dataclasses.replace(result, precision=precision, backend="schur")
    r = precision.redundancy
    low, high = scipy.stats.chi2.ppf([0.025, 0.975], r)
    assert not low <= 1.5 * r <= high
    points = project.spec.points.values()
    n_fixed = sum(s == 0 for p in points for s in p.sigma)
    n_weighted = sum(s is not None and s > 0 for p in points for s in p.sigma)
    n_control = sum(any(s is not None for s in p.sigma) for p in points)
    datum = (f"control: {n_control} control points ({n_fixed} fixed, {n_weighted} weighted"
             f" coordinates), {len(project.spec.distances)} distances")
    group = result.problem.groups[0]
    flagged = (f"image {project.image_ids[int(group.image[0])]}"
               f" point {project.point_ids[int(group.point[0])]} y")
    test = (f"chi-square test FAILED: r sigma0^2/prior^2 = {1.5 * r:.1f} not in"
            f" [{low:.1f}, {high:.1f}]")
    outliers = (f"1 with |w| > {CRITICAL:.2f} (alpha 0.001 per test): image_points:C1 {flagged}"
                " |w| 4.50; 1 removed by data snooping")
    header = out_text(project, result).split("\n\n")[1]
    for key, value in (("variance test", test), ("datum", datum), ("solver backend", "schur"),
                       ("outliers", outliers), ("timings", "not timed")):
        assert re.search(rf"^  {key} +{re.escape(value)}", header, re.M), key
    data = results_dict(project, result)
    assert data["solver"] == "schur"
    assert data["datum"] == {"kind": "control", "description": datum}
    variance = data["variance_test"]
    assert variance["passed"] is False and variance["redundancy"] == r
    assert variance["statistic"] == pytest.approx(1.5 * r, rel=1e-12)
    assert [variance["low"], variance["high"]] == pytest.approx([low, high], rel=1e-12)
    assert variance["sigma0_high"] == pytest.approx(math.sqrt(high / r), rel=1e-12)
    assert data["outliers"] == {
        "critical_value": CRITICAL, "alpha": 0.001, "count": 1, "removed": 1,
        "worst": [{"group": "image_points:C1", "observation": flagged, "abs_w": 4.5}],
    }
    lines = summary_lines(project, result)
    assert f"  {test}" in [line[:len(test) + 2] for line in lines]
    assert f"datum: {datum}" in lines and f"outliers: {outliers}" in lines
    warning = next(line for line in warning_lines(project, result) if "chi-square" in line)
    assert f"{math.sqrt(low / r):.4g} to {math.sqrt(high / r):.4g} expected" in warning


def test_res_of_a_pixel_project_is_in_pixels():
    """A pixel project with a mm camera model (DBAT's camcal): NAME.res in pixels as the image
    points were given, x y the file's values, v turned into (col, row) pixels."""
    project = jaxba.build_project(jaxba.read_project(CONFIGS / "dbat_camcal.toml"))
    assert project.spec.image_units == "pixel"
    result = _fake_result(project)
    text = res_text(project, result)
    assert "x y vx vy in pixels (col, row: row down)" in text
    assert "vx_px" not in text and " mm" not in text
    rows = _data_lines(text)
    table = project.spec.image_points
    given = {(i, p): xy for i, p, xy in zip(table.image, table.point, table.xy)}
    group = result.problem.groups[0]
    pixel = np.asarray(project.pixel_grids["C1"].pixel_size)
    v = {(project.image_ids[i], project.point_ids[p]): result.residuals[0][k] for k, (i, p) in
         enumerate(zip(np.asarray(group.image).tolist(), np.asarray(group.point).tolist()))}
    assert len(rows) == len(given) == len(v)
    printed = np.array([[float(x) for x in row[2:6]] for row in rows])
    keys = [(row[0], row[1]) for row in rows]
    np.testing.assert_allclose(printed[:, :2], [given[key] for key in keys], rtol=0, atol=5e-5)
    expected = np.array([v[key] / pixel * [1.0, -1.0] for key in keys])
    np.testing.assert_allclose(printed[:, 2:], expected, rtol=0, atol=5e-5)
    rms = next(line for line in text.splitlines() if line.startswith("# RMS all")).split()
    assert float(rms[rms.index("vy") + 1]) == pytest.approx(
        math.sqrt(np.mean(expected[:, 1] ** 2)), abs=5e-4)


def test_board_warp_in_out_json_and_html(tmp_path):
    """A warped board (`board_warp = true`): kx, ky with σ in NAME.out, results.json, the
    HTML report and the console summary, ρ(kx, ky) and their correlations with the camera's
    estimated IOPs from the covariance (recomputed here); nothing of it without the key."""
    file = write_project(tmp_path, 0, warp=(1.0, -0.5), board_warp=True, name="bent")
    project = jaxba.build_project(jaxba.read_project(file))
    result = _fake_result(project)
    result = dataclasses.replace(result, parameters=eqx.tree_at(
        lambda p: p.warp, result.parameters, np.array([[0.8125, -0.4375]])))
    data = results_dict(project, result)["board_warp"]
    assert data["kx"] == {"value": 0.8125, "std": STD_OBJ}
    assert data["ky"] == {"value": -0.4375, "std": STD_OBJ}
    covariance = np.zeros((flatten(result.parameters).size,) * 2)
    index = result.precision.free_index
    covariance[np.ix_(index, index)] = result.precision.covariance
    position = unflatten(result.parameters, np.arange(covariance.shape[0]))
    warp = np.asarray(position.warp)[0]
    model, row = project.camera_rows["C1"]
    free = np.asarray(project.problem.free.cameras[model])[row]
    iop = np.asarray(position.cameras[model])[row][free]
    chosen = np.concatenate([warp, iop])
    block = covariance[np.ix_(chosen, chosen)]
    rho = block / np.sqrt(np.outer(np.diag(block), np.diag(block)))
    assert data["correlation"] == pytest.approx(rho[0, 1], rel=MATRIX_RTOL)
    entry = data["camera_correlations"]["C1"]
    names = jaxba.CAMERA_MODELS[model].parameter_names
    assert entry["parameters"] == [n for n, f in zip(names, free) if f]
    np.testing.assert_allclose([entry["kx"], entry["ky"]], rho[:2, 2:], rtol=MATRIX_RTOL)
    text = out_text(project, result)
    table = text[text.index("Board warp"):].splitlines()
    assert table[1].split() == ["board", "kx", "ky", "skx", "sky", "rho"]
    assert table[2].split() == ["board", "0.81250", "-0.43750", "0.00020", "0.00020",
                                f"{rho[0, 1]:.2f}"]
    assert f"  board kx  {rho[0, 2]:.2f}" in text
    console = summary_lines(project, result)
    start = console.index("board board warp (object units)")
    assert console[start + 1:start + 3] == ["  kx   8.12500000e-01 +/- 2.00e-04",
                                            "  ky  -4.37500000e-01 +/- 2.00e-04"]
    figures = {figure.name: b"" for figure in jaxba.figure_set(project, result)}
    page = jaxba.html_report(project, result, figures=figures)
    section = page[page.index('<section id="warp">'):]
    section = section[:section.index("</section>")]
    assert "<td>0.81250</td><td>-0.43750</td><td>0.0002</td><td>0.0002</td>" in section
    assert "Correlations with the IOPs of camera C1" in section
    flat = jaxba.build_project(jaxba.read_project(
        write_project(tmp_path / "flat", 0, name="flat")))
    flat_result = _fake_result(flat)
    assert "board_warp" not in results_dict(flat, flat_result)
    assert "Board warp" not in out_text(flat, flat_result)
    assert not any(line.startswith("board") for line in summary_lines(flat, flat_result))
