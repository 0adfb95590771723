"""The result by ID (`Adjustment.cameras`, `images`, `points`, `observations`, `summary()`),
checked against the project's tables and the result's arrays by row number, on the
session's synthetic block (the project path) and on `jaxba.adjust` with and without labels."""

import dataclasses
import sys

import jax
import numpy as np
import pytest
import scipy.stats
from board_scene import write_project

import jaxba
from jaxba._statistics._by_id import observation_columns
from jaxba._statistics._ids import ids_from_labels, index_ids

PRINTED = 1e-9  # observations.csv writes 10 significant digits


def _file_status(sigma) -> str:
    """The status a σ of the input tables gives: None free, 0 fixed, > 0 weighted."""
    return "free" if sigma is None else "fixed" if sigma == 0 else "weighted"


@pytest.fixture(scope="module")
def block(synthetic_block):
    _, project, result = synthetic_block
    return project, result


def test_cameras_by_id(block):
    project, result = block
    model, row = project.camera_rows["C1"]
    spec = project.spec.cameras["C1"]
    camera = result.cameras["C1"]
    names = jaxba.CAMERA_MODELS[model].parameter_names
    assert list(camera) == list(names) and camera.id == "C1" and camera.model == model
    values = np.asarray(result.parameters.cameras[model][row])
    std = np.asarray(result.precision.std.cameras[model][row])
    for k, name in enumerate(names):
        estimate = camera[name]
        assert estimate.value == values[k]
        expected = ("weighted" if name in spec.sigma else "free" if name in spec.free
                    else "fixed")
        assert estimate.status == expected, name
        assert (estimate.sigma is None) == (expected == "fixed"), name
        if estimate.sigma is not None:
            assert estimate.sigma == std[k] > 0
    assert camera["c"].value == pytest.approx(8.5, abs=0.05)  # the synthetic camera's


def test_images_by_id_in_radians_with_status(block):
    project, result = block
    pose = jaxba.POSE_MODELS[result.problem.pose]
    for k, iid in enumerate(project.image_ids):
        image = result.images[iid]
        assert list(image) == list(pose.parameter_names)
        for j, name in enumerate(image):
            estimate = image[name]
            assert estimate.value == np.asarray(result.parameters.images)[k, j]
            assert estimate.status == _file_status(project.spec.images[iid].eop_sigma[j])
            assert estimate.unit == ("rad" if name in ("omega", "phi", "kappa") else None)


def test_points_by_id_with_covariance_and_kind(block):
    project, result = block
    covariance = jaxba.full_covariance(result)
    positions = jaxba.advanced.unflatten(result.parameters,
                                np.arange(jaxba.advanced.flatten(result.parameters).size)).points
    kinds = set()
    for k, pid in enumerate(project.point_ids):
        point = result.points[pid]
        status = tuple(_file_status(s) for s in project.spec.points[pid].sigma)
        assert point.status == status
        assert point.kind == ("tie" if status == ("free",) * 3 else "control")
        kinds.add(point.kind)
        np.testing.assert_array_equal(point.coordinates, np.asarray(result.parameters.points)[k])
        block_ = covariance[np.ix_(positions[k], positions[k])]
        np.testing.assert_allclose(point.covariance, block_, rtol=1e-12, atol=0)
        free = np.array([s != "fixed" for s in status])
        np.testing.assert_allclose(point.sigmas[free], np.sqrt(np.diag(block_))[free],
                                   rtol=1e-12)
        assert np.all(np.isnan(point.sigmas[~free]))
        assert [point[n].sigma is None for n in ("X", "Y", "Z")] == list(~free)
    assert kinds == {"tie", "control"}
    assert isinstance(point.covariance, np.ndarray)


def test_unknown_ids_name_the_id_and_valid_ones(block):
    project, result = block
    with pytest.raises(KeyError, match=r"no point 'P7' \(there are \d+: '1', '2'"):
        result.points["P7"]
    with pytest.raises(KeyError, match="no image 'img99'.*'img01'"):
        result.images["img99"]
    with pytest.raises(KeyError, match="no camera 'C9'.*'C1'"):
        result.cameras["C9"]
    with pytest.raises(KeyError, match="no parameter 'f'.*'xp', 'yp', 'c'"):
        result.cameras["C1"]["f"]
    assert "img01" in result.images and len(result.points) == len(project.point_ids)


def test_observations_table(block, monkeypatch):
    project, result = block
    monkeypatch.setitem(sys.modules, "pandas", None)  # the dict of columns without pandas
    table = result.observations
    assert isinstance(table, dict)
    n = len(project.spec.image_points)
    assert all(len(column) == n for column in table.values())
    # Every row against the result by row number: v of its group and row, r and w.
    group, = [g for g in result.problem.groups if isinstance(g, jaxba.ImagePoints)]
    k = result.problem.groups.index(group)
    row_of = {(project.image_ids[i], project.point_ids[p]): r for r, (i, p) in
              enumerate(zip(np.asarray(group.image).tolist(), np.asarray(group.point).tolist()))}
    rows = np.array([row_of[key] for key in zip(table["image"], table["point"])])
    np.testing.assert_array_equal(np.column_stack([table["x"], table["y"]]),
                                  np.asarray(group.measured)[rows])
    np.testing.assert_array_equal(np.column_stack([table["vx"], table["vy"]]),
                                  np.asarray(result.residuals[k])[rows])
    np.testing.assert_array_equal(np.column_stack([table["wx"], table["wy"]]),
                                  result.reliability.normalised_residuals[k][rows])
    np.testing.assert_array_equal(np.column_stack([table["rx"], table["ry"]]),
                                  result.reliability.redundancy_numbers[k][rows])
    assert set(table["camera"]) == {"C1"} and not table["removed"].any()
    critical = result.reliability.critical_value
    np.testing.assert_array_equal(
        table["outlier"], np.maximum(abs(table["wx"]), abs(table["wy"])) > critical)
    # Sorted by image as the .res file, the image points of one image in file order.
    order = [project.image_ids.index(i) for i in table["image"]]
    assert order == sorted(order)


def test_observations_as_a_data_frame(block):
    pandas = pytest.importorskip("pandas")
    _, result = block
    frame = result.observations
    assert isinstance(frame, pandas.DataFrame)
    assert list(frame.columns)[:8] == ["image", "point", "camera", "group", "x", "y", "vx", "vy"]
    columns = observation_columns(result, result.ids)
    for name in ("wx", "vy", "outlier"):
        np.testing.assert_array_equal(frame[name].to_numpy(), columns[name])


def test_summary_names_the_facts(block):
    _, result = block
    text = result.summary()
    r = result.precision.redundancy
    low, high = scipy.stats.chi2.ppf([0.025, 0.975], r)
    statistic = r * result.precision.sigma0_squared  # a priori σ0 1
    assert f"r sigma0^2/prior^2 = {statistic:.1f} in [{low:.1f}, {high:.1f}]" in text
    assert ("passed" if low <= statistic <= high else "FAILED") in text
    assert f"redundancy {r}" in text and "dense backend" in text
    assert "control: 3 control points (6 fixed, 0 weighted coordinates), 4 distances" in text
    critical = result.reliability.critical_value
    with np.errstate(invalid="ignore"):
        large = sum(int(np.sum(np.abs(w) > critical))
                    for w in result.reliability.normalised_residuals)
    assert f"{large} with |w| > {critical:.2f}" in text
    assert "seconds: datum check" in text and "solve" in text
    assert text.splitlines()[0].startswith("solver         converged after")


def test_summary_lists_the_estimated_camera_parameters_with_sigma(block):
    """Every free parameter of the project's camera with its value and σ (from the flat
    unknowns; σ printed to 3 digits: within 0.6 %), no fixed one."""
    project, result = block
    lines = result.summary().splitlines()
    model, row = project.camera_rows["C1"]
    free = project.spec.cameras["C1"].free
    first = lines.index(f"camera C1 ({model})")
    assert [line.split()[0] for line in lines[first + 1:first + 1 + len(free)]] == [
        name for name in jaxba.CAMERA_MODELS[model].parameter_names if name in free]
    for line in lines[first + 1:first + 1 + len(free)]:
        name, value, plus_minus, sigma = line.split()
        assert plus_minus == "+/-"
        k = jaxba.CAMERA_MODELS[model].parameter_names.index(name)
        assert float(value) == pytest.approx(
            float(np.asarray(result.parameters.cameras[model])[row, k]), rel=1e-8)
        assert float(sigma) == pytest.approx(
            float(np.asarray(result.precision.std.cameras[model])[row, k]), rel=6e-3)
    assert first + 1 + len(free) == len(lines)


def test_adjust_with_and_without_labels(block):
    project, result = block
    labelled = jaxba.adjust(project.problem, labels=project.labels)
    assert labelled.cameras["C1"]["c"] == result.cameras["C1"]["c"]
    assert list(labelled.points) == project.point_ids
    plain = jaxba.adjust(project.problem)
    assert list(plain.images) == list(range(len(project.image_ids)))
    assert plain.images[0]["X0"] == result.images[project.image_ids[0]]["X0"]
    assert plain.cameras[0]["c"] == result.cameras["C1"]["c"]
    with pytest.raises(KeyError, match="no image 'img01'.*0, 1, 2"):
        plain.images["img01"]
    assert list(dataclasses.replace(result, ids=None).cameras) == [0]
    for adjusted in (labelled, plain):
        assert all(isinstance(leaf, np.ndarray) for leaf in jax.tree.leaves(
            (adjusted.parameters, adjusted.precision.std)))


def test_labels_of_another_form_are_refused(block):
    project, _ = block
    labels = list(project.labels)
    ids = ids_from_labels(project.problem.initial, labels)
    assert ids.images == tuple(project.image_ids) and ids.points == tuple(project.point_ids)
    assert ids.cameras == {"smac": ("C1",)}
    position = labels.index(f"image {project.image_ids[1]} X0")
    labels[position] = "station 2"
    with pytest.raises(ValueError, match=r"labels\[\d+\] = 'station 2': expected image <id> X0"):
        jaxba.adjust(project.problem, labels=labels)
    labels[position] = f"image {project.image_ids[0]} X0"
    with pytest.raises(ValueError, match="image ID 'img01' names two rows"):
        ids_from_labels(project.problem.initial, labels)



def test_boards_by_id(block, tmp_path):
    """A warped board's kx, ky by ID (`Adjustment.boards`), as the result's arrays, status
    free; its ID from the labels ("board board kx"), row numbers without; no boards without
    a warp."""
    file = write_project(tmp_path, 0, warp=(1.0, -0.5), board_warp=True, name="bent")
    project = jaxba.build_project(jaxba.read_project(file))
    result = jaxba.adjust_project(project)
    board = result.boards["board"]
    assert list(result.boards) == ["board"] and list(board) == ["kx", "ky"]
    assert board.id == "board" and board.model == "warp"
    values = np.asarray(result.parameters.warp)[0]
    std = np.asarray(result.precision.std.warp)[0]
    for k, name in enumerate(("kx", "ky")):
        assert board[name].value == values[k] and board[name].sigma == std[k] > 0
        assert board[name].status == "free" and board[name].unit is None
    assert ids_from_labels(result.parameters, project.labels).boards == ("board",)
    assert index_ids(result.parameters).boards == (0,)
    with pytest.raises(KeyError, match="no board 'other' \\(there are 1: 'board'\\)"):
        result.boards["other"]
    assert list(block[1].boards) == []
