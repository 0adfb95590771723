"""DBAT scripts in their general forms (`jaxba._io._dbat`): synthetic scripts written here,
imported and adjusted back to the truth; unsupported elements refused by name.

The scene: the synthetic lab's wall of targets (`jaxba._io._synthetic`) seen by 8 images of a
distortion-free camera (where DBAT's lens model 3 and SMAC coincide: x = -c U/W), measured in
DBAT's pixels (origin at the top-left image corner, row down).
"""

import dataclasses
import pathlib

import numpy as np
import pytest

import jaxba
from jaxba._io import _synthetic as synthetic
from jaxba._io._dbat import read_script, write_dbat_project

C = 8.5  # mm
COLUMNS, ROWS = synthetic.SENSOR
PS = synthetic.PIXEL_SIZE[0]
NOISE_PX = 0.02
STATION_ATOL = 2e-3  # m: the adjusted stations against the truth (noise 0.02 px)
POINT_ATOL = 1e-3  # m
SCALE_RTOL = 1e-3  # a dependent datum: distances against the truth's


@dataclasses.dataclass(frozen=True)
class Scene:
    points: np.ndarray  # (n, 3) m
    eops: np.ndarray  # (n_images, 6): X0 Y0 Z0 m, omega phi kappa degrees
    marks: list  # (image 1.., point 1.., col, row) DBAT pixels


@pytest.fixture(scope="module")
def scene() -> Scene:
    rng = np.random.default_rng(7)
    points = synthetic.make_targets(rng, 40)
    stations, matrices = synthetic.make_stations(rng, 8, 1)
    iop = dict.fromkeys(synthetic.IOP_NAMES, 0.0) | {"c": C}
    eops, marks = [], []
    for k, (station, m) in enumerate(zip(stations, matrices), start=1):
        eops.append([*station, *np.degrees(synthetic.opk_from_rotation(m))])
        index, xy = synthetic.observe(points, station, m, iop)
        xy = xy + rng.normal(0.0, NOISE_PX * PS, xy.shape)
        marks += [(k, int(j) + 1, x / PS + COLUMNS / 2, ROWS / 2 - y / PS)
                  for j, (x, y) in zip(index, xy)]
    return Scene(points, np.array(eops), marks)


def _camera_xml(sensor: str, with_id: bool = True) -> str:
    return ("<camera>" + ("<id>1</id>" if with_id else "") + "<name>synthetic</name>"
            f"<unit>mm</unit><sensor>{sensor}</sensor><image>{COLUMNS},{ROWS}</image>"
            f"<aspect>1</aspect><focal>{C}</focal><cc>{C}</cc><pp>default</pp>"
            "<model>3</model><nK>3</nK><nP>2</nP><K>0,0,0</K><P>0,0</P></camera>")


def _lines(rows) -> str:
    return "# written by test_dbat_scripts\n" + "".join(",".join(map(str, r)) + "\n"
                                                      for r in rows)


def _script(folder: pathlib.Path, inputs: str, operations: str) -> pathlib.Path:
    path = folder / "script.xml"
    path.write_text('<?xml version="1.0" encoding="UTF-8"?>\n<document dbat_script_version='
                    f'"1.0"><meta><name>test</name></meta><input base_dir="$HERE">{inputs}'
                    f"</input><operations>{operations}</operations></document>\n")
    return path


def _images(folder: pathlib.Path, n: int) -> str:
    (folder / "images.txt").write_text(_lines((k, f"x/IMG_{k:02d}.JPG") for k in
                                              range(1, n + 1)))
    return '<images><file format="id,path">images.txt</file></images>'


def _adjust(path: pathlib.Path):
    spec = jaxba.read_project(path)
    if not spec.complete:
        spec, _ = jaxba.complete_project(spec)
    project = jaxba.build_project(spec)
    result = jaxba.adjust_project(project)
    assert result.converged
    return project, result


def _stations(project, result) -> dict[str, np.ndarray]:
    eop = np.asarray(result.parameters.images)
    return {iid: eop[k, :3] for k, iid in enumerate(project.image_ids)}


def _points(project, result) -> dict[str, np.ndarray]:
    xyz = np.asarray(result.parameters.points)
    return {pid: xyz[k] for k, pid in enumerate(project.point_ids)}


@pytest.mark.slow  # the block initialisation's compilation: about 18 s on 2 cores
def test_control_in_3d_two_mark_files_and_an_inline_camera(scene, tmp_path):
    """Non-coplanar fixed control `id,x,y,z` (no planar resection: jaxba computes the EOPs),
    two image_pts files with their own column orders and σ, an inline camera without <id>
    and with its sensor in mm, the camera fixed."""
    control = [1, 5, 12, 20, 28, 33, 37, 40]
    (tmp_path / "ctrl.txt").write_text(_lines(
        (j, *scene.points[j - 1]) for j in control))
    first = [m for m in scene.marks if m[0] <= 4]
    second = [m for m in scene.marks if m[0] > 4]
    (tmp_path / "a.txt").write_text(_lines(first))
    (tmp_path / "b.txt").write_text(_lines((p, i, x, y, 0.03, 0.04) for i, p, x, y in second))
    inputs = ('<ctrl_pts><file format="id, x, y, z">ctrl.txt</file></ctrl_pts>'
              + _images(tmp_path, 8)
              + '<image_pts><file format="im,id,x,y" sxy="0.02">a.txt</file>'
              '<file format="id,im,x,y,sx,sy">b.txt</file></image_pts>'
              f"<cameras>{_camera_xml(f'{COLUMNS * PS},{ROWS * PS}', with_id=False)}</cameras>")
    operations = ('<operation min_rays="2">check_ray_count</operation>'
                  "<operation><set_initial_values><io>loaded</io></set_initial_values>"
                  "</operation><operation><set_bundle_estimate_params><io>false</io>"
                  "<eo>true</eo><op>default</op></set_bundle_estimate_params></operation>"
                  "<operation>spatial_resection</operation><operation>bundle_adjustment"
                  "</operation>")
    written = write_dbat_project(_script(tmp_path, inputs, operations), tmp_path / "out",
                                 name="dbat")
    assert written.images == {}  # no coplanar control: every EOP left to jaxba
    spec = jaxba.read_project(written.project_file)
    camera = spec.cameras["C1"]
    assert camera.free == frozenset() and camera.values["c"] == C
    assert camera.pixel_size == pytest.approx((PS, PS), rel=1e-12)
    sigma = {(m.image, m.point): m.sigma for m in spec.image_points}
    assert {s for (i, _), s in sigma.items() if i == "IMG_01"} == {(0.02, 0.02)}
    assert {s for (i, _), s in sigma.items() if i == "IMG_08"} == {(0.03, 0.04)}
    assert all(spec.points[str(j)].sigma == (0.0, 0.0, 0.0) for j in control)
    project, result = _adjust(written.project_file)
    for k, xyz in _stations(project, result).items():
        np.testing.assert_allclose(xyz, scene.eops[int(k[-2:]) - 1, :3], atol=STATION_ATOL)
    for pid, xyz in _points(project, result).items():
        np.testing.assert_allclose(xyz, scene.points[int(pid) - 1], atol=POINT_ATOL)


def test_no_control_prior_eo_and_a_dependent_datum(scene, tmp_path):
    """No control; `<prior_eo>` in degrees (the truth: the starting values), the camera in
    its own file with sensor auto, `set_datum depend` with ref_cam 3: datum "dependent" on
    image IMG_03; adjusted to the truth (the datum's values are the truth's)."""
    (tmp_path / "eo.txt").write_text(_lines((k, *eop) for k, eop in
                                            enumerate(scene.eops, start=1)))
    (tmp_path / "marks.txt").write_text(_lines((i, p, x, y, 0.02) for i, p, x, y in scene.marks))
    (tmp_path / "cam.xml").write_text(f'<document dbat_camera_version="1.0"><cameras>'
                                      f"{_camera_xml(f'auto,{ROWS * PS}')}</cameras></document>")
    inputs = (_images(tmp_path, 8) + '<prior_eo><file format="id,x,y,z,omega,phi,kappa" '
              'units="degrees">eo.txt</file></prior_eo><image_pts><file format="im,id,x,y,sxy">'
              "marks.txt</file></image_pts><cameras><file>cam.xml</file></cameras>")
    operations = ("<operation><set_initial_values><io><all>loaded</all></io><eo>loaded</eo>"
                  "</set_initial_values></operation><operation><set_bundle_estimate_params>"
                  "<io><all>false</all></io><eo><all>true</all></eo><op><all>true</all></op>"
                  "</set_bundle_estimate_params></operation><operation>forward_intersection"
                  '</operation><operation><set_datum ref_cam="3">depend</set_datum></operation>'
                  "<operation>bundle_adjustment></operation>")
    written = write_dbat_project(_script(tmp_path, inputs, operations), tmp_path / "out",
                                 name="dep")
    assert written.images["IMG_05"] == pytest.approx(tuple(scene.eops[4]), abs=1e-12)
    project, result = _adjust(written.project_file)
    assert project.datum["kind"] == "dependent" and project.datum["image"] == "IMG_03"
    assert project.datum["scale"] == "base"
    stations = _stations(project, result)
    np.testing.assert_array_equal(stations["IMG_03"], scene.eops[2, :3])  # fixed
    for k, xyz in stations.items():
        np.testing.assert_allclose(xyz, scene.eops[int(k[-2:]) - 1, :3], atol=STATION_ATOL)
    points = _points(project, result)
    a, b = points["1"] - points["40"], scene.points[0] - scene.points[39]
    assert np.linalg.norm(a) == pytest.approx(np.linalg.norm(b), rel=SCALE_RTOL)


def test_weighted_control_check_points_and_filters(scene, tmp_path):
    """`id,label,x,y,z,sx,sy,sz` weighted control, a subset kept as check points by filters;
    the check points are free points in the project, the control weighted per coordinate."""
    rows = [(j, f"T{j}", *scene.points[j - 1], 0.001, 0.002, 0.003) for j in (1, 5, 12, 20, 28)]
    (tmp_path / "ref.txt").write_text(_lines(rows))
    (tmp_path / "marks.txt").write_text(_lines(scene.marks))
    fmt = "id,label,x,y,z,sx,sy,sz"
    inputs = (f'<ctrl_pts><file format="{fmt}">ref.txt</file><filter id="12,28">remove</filter>'
              f'</ctrl_pts><check_pts><file format="{fmt}">ref.txt</file>'
              '<filter id="12,28">keep</filter></check_pts>' + _images(tmp_path, 8)
              + '<image_pts><file format="im,id,x,y" sxy="0.02">marks.txt</file></image_pts>'
              f"<cameras>{_camera_xml(f'auto,{ROWS * PS}')}</cameras>")
    script = read_script(_script(tmp_path, inputs, ""))
    assert sorted(script.control) == ["1", "20", "5"] and sorted(script.check) == ["12", "28"]
    written = write_dbat_project(script.path, tmp_path / "out", name="w")
    spec = jaxba.read_project(written.project_file)
    assert spec.points["5"].sigma == (0.001, 0.002, 0.003)
    assert spec.points["12"].sigma == (None, None, None)
    assert spec.points["12"].xyz == pytest.approx(tuple(scene.points[11]), abs=1e-12)


@pytest.mark.parametrize("change, message", [
    (("<operation>bundle_adjustment</operation>", "<operation>bundle</operation>"),
     "unsupported operation 'bundle'"),
    (('format="im,id,x,y"', 'format="im,id,row,col"'), "unknown column 'row'"),
    (("<model>3</model>", "<model>1</model>"), "<model>: only DBAT's lens model 3"),
    (("<cameras>", "<cameras><lens/>"), "<cameras>: unsupported element <lens>"),
    (("<images>", "<gcp_file/><images>"), "<input>: unsupported element <gcp_file>"),
    (("<operation>bundle_adjustment</operation>",
      '<operation><set_datum ref_cam="1" ref_base="x">depend</set_datum></operation>'),
     "ref_base 'x' is not supported"),
])
def test_unsupported_elements_are_named(scene, tmp_path, change, message):
    (tmp_path / "marks.txt").write_text(_lines(scene.marks))
    (tmp_path / "ctrl.txt").write_text(_lines((j, *scene.points[j - 1]) for j in (1, 5, 12)))
    inputs = ('<ctrl_pts><file format="id,x,y,z">ctrl.txt</file></ctrl_pts>'
              + _images(tmp_path, 8)
              + '<image_pts><file format="im,id,x,y" sxy="0.02">marks.txt</file></image_pts>'
              f"<cameras>{_camera_xml(f'auto,{ROWS * PS}')}</cameras>")
    path = _script(tmp_path, inputs, "<operation>bundle_adjustment</operation>")
    path.write_text(path.read_text().replace(*change))
    with pytest.raises(ValueError) as error:
        write_dbat_project(path, tmp_path / "out")
    assert message in str(error.value)
    assert ("marks.txt" if "column" in message else "script.xml") in str(error.value)
    assert not (tmp_path / "out").exists()


def test_an_undefined_datum_is_refused(scene, tmp_path):
    (tmp_path / "marks.txt").write_text(_lines(scene.marks))
    inputs = (_images(tmp_path, 8) + '<image_pts><file format="im,id,x,y" sxy="0.02">'
              f"marks.txt</file></image_pts><cameras>{_camera_xml(f'auto,{ROWS * PS}')}"
              "</cameras>")
    with pytest.raises(ValueError, match="the datum is undefined"):
        write_dbat_project(_script(tmp_path, inputs, ""), tmp_path / "out")
