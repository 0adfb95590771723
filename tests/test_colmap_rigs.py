"""COLMAP's rigs and frames (COLMAP 3.12 and later) in and out of jaxba projects.

In: a model written by pycolmap (tests/data/colmap_rig, text and binary: a stereo rig with an
IMU, a camera alone) imports as a project whose rig composes to the images' poses COLMAP
computed itself. Out and back: a synthetic stereo rig project, adjusted, exported (`jaxba
export --format colmap`) and imported (`jaxba import colmap`) has the same pose in the rig
and the same frames; pycolmap, where installed, reads the export as the same rig.
"""

import contextlib
import dataclasses
import io
import json
import pathlib
import shutil
import tomllib

import jax
import numpy as np
import pytest
from board_scene import board, project, stations, write_pixel_project

import jaxba
from jaxba._cli._main import main
from jaxba._io._colmap import (
    ColmapRig,
    colmap_pose_to_eop,
    eop_to_colmap_pose,
    matrix_to_quaternion,
    quaternion_to_matrix,
    read_colmap_model,
    write_colmap,
    write_colmap_model,
    write_colmap_project,
)
from jaxba._io._colmap._poses import compose, inverse, rigid
from jaxba._models._rotation_numpy import opk_to_matrix
from jaxba._statistics._rigs import composed_poses

jax.config.update("jax_enable_x64", True)

FIXTURE = pathlib.Path(__file__).resolve().parent / "data" / "colmap_rig"
POSE_ATOL = 1e-12  # radians and object units (|X| ~ 1): conversions of exact poses
ROUND_TRIP_ATOL = 1e-9  # mm and degrees: results.json -> COLMAP text -> rigs.toml, as asked
EOP = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
MOUNT = np.array([120.0, 3.0, -2.0, 1.0, -4.0, 0.7])  # the right camera in the rig (mm, deg)
LEFT = {"fx": 540.0, "fy": 538.0, "cx": 330.0, "cy": 242.0, "skew": 0.0,
        "k1": -0.25, "k2": 0.08, "p1": 0.001, "p2": -0.0005, "k3": 0.0}
RIGHT = {**LEFT, "fx": 545.0, "fy": 544.0, "cx": 318.0, "cy": 236.0, "k1": -0.21}
FREE = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"]
NOISE_PX = 0.2


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def _pose(entries: dict) -> np.ndarray:
    """(6,) radians of results.json's X0 .. kappa entries (degrees)."""
    values = np.array([entries[name]["value"] for name in EOP])
    return np.r_[values[:3], np.radians(values[3:])]


def _cam_from_world(eop) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's (R, t) of jaxba EOPs (radians), through the tested image conversion."""
    q, t = eop_to_colmap_pose(eop)
    return quaternion_to_matrix(q), t


# --- in: pycolmap's model -----------------------------------------------------------------------


def test_text_and_binary_are_the_same_model():
    """pycolmap wrote one reconstruction both ways; both readers give the same records
    (its text keeps 17 digits: the same doubles)."""
    text, binary = (read_colmap_model(FIXTURE / kind) for kind in ("text", "binary"))
    assert text == binary
    assert sorted(text.rigs) == [1, 2] and sorted(text.frames) == [1, 2, 3, 4, 5]
    assert text.rigs[1].reference == ("CAMERA", 1)
    assert [sensor for sensor, _ in text.rigs[1].sensors] == [("CAMERA", 2), ("IMU", 1)]
    assert text.rigs[2].sensors == ()
    assert text.frames[1].data == (("CAMERA", 1, 1), ("CAMERA", 2, 2))


@pytest.mark.parametrize("kind", ["text", "binary"])
def test_a_rig_imports_and_composes_to_colmaps_image_poses(kind, tmp_path):
    """The stereo rig becomes rig1 (reference camera 1, camera 2 free in it), its three
    frames the frames table, the IMU is left out with a warning, camera 3 (alone in its rig)
    imports as before. Independent check: every image's pose composed by jaxba from its frame
    and its camera's pose in the rig (docs/conventions.md) is the cam_from_world COLMAP
    computed itself (images.txt)."""
    warnings = []
    written = write_colmap_project(FIXTURE / kind, tmp_path, warn=warnings.append)
    assert warnings == ["rig 1: sensor IMU 1 left out: jaxba's rigs are of cameras"]
    assert (written.n_rigs, written.n_frames, written.n_images) == (1, 3, 8)
    rigs = tomllib.loads((tmp_path / "rigs.toml").read_text())
    assert list(rigs) == ["rig1"] and rigs["rig1"]["reference"] == "1"
    assert set(rigs["rig1"]["2"]["free"]) == set(EOP)
    frames = [line.split() for line in (tmp_path / "frames.txt").read_text().splitlines()
              if not line.startswith("#")]
    assert frames == [[f"cam{c}_{i:02d}.png", str(f)]
                      for f, (c, i) in zip((1, 1, 2, 2, 3, 3),
                                           ((1, 1), (2, 2), (1, 3), (2, 4), (1, 5), (2, 6)))]

    project = jaxba.build_project(jaxba.read_project(written.project_file))
    layout = project.rigs
    assert layout.frame_ids == ["1", "2", "3", "cam3_07.png", "cam3_08.png"]
    composed = composed_poses(project.problem.initial, "opk", layout.image_frame,
                              layout.image_mount)
    colmap = {image.name: image for image in read_colmap_model(FIXTURE / "text").images.values()}
    for k, image_id in enumerate(project.image_ids):
        expected = colmap_pose_to_eop(colmap[image_id].qvec, colmap[image_id].tvec)
        np.testing.assert_allclose(composed[k], expected, rtol=0, atol=POSE_ATOL)
    # The datum: the first image's pose and one coordinate of the next reference image's.
    free = np.asarray(project.problem.free.images)
    assert not free[0].any() and free[1].sum() == 5 and free[2:].all()


def test_an_imu_as_the_reference_sensor_gives_the_same_camera_rig(tmp_path):
    """The fixture's stereo rig re-expressed with its IMU as the reference sensor (every
    sensor_from_rig and rig_from_world moved into the IMU's frame): camera 1 is the reference
    again, camera 2's pose in the rig and every image's pose as before."""
    model = read_colmap_model(FIXTURE / "text")
    ((_, imu_from_camera1),) = [(s, p) for s, p in model.rigs[1].sensors if s[0] == "IMU"]
    ((_, camera2_from_camera1),) = [(s, p) for s, p in model.rigs[1].sensors if s[1] == 2]
    to_imu = rigid(*imu_from_camera1)

    def pose(r_t):
        return tuple(matrix_to_quaternion(r_t[0])), tuple(r_t[1])

    rig = ColmapRig(1, ("IMU", 1), ((("CAMERA", 1), pose(inverse(to_imu))),
                                    (("CAMERA", 2), pose(compose(rigid(*camera2_from_camera1),
                                                                 inverse(to_imu))))))
    frames = {fid: dataclasses.replace(frame, qvec=q, tvec=t) if frame.rig_id == 1 else frame
              for fid, frame in model.frames.items()
              for q, t in [pose(compose(to_imu, rigid(frame.qvec, frame.tvec)))]}
    write_colmap_model(dataclasses.replace(model, rigs={**model.rigs, 1: rig}, frames=frames),
                       tmp_path / "imu")
    before = write_colmap_project(FIXTURE / "text", tmp_path / "before", warn=lambda m: None)
    after = write_colmap_project(tmp_path / "imu", tmp_path / "after", warn=lambda m: None)
    spec_before, spec_after = (jaxba.read_project(p.project_file) for p in (before, after))
    assert spec_after.rigs["rig1"].reference == "1"
    np.testing.assert_allclose([spec_after.rigs["rig1"].mounts["2"].values[n] for n in EOP],
                               [spec_before.rigs["rig1"].mounts["2"].values[n] for n in EOP],
                               rtol=0, atol=POSE_ATOL)
    for image_id, image in spec_before.images.items():
        np.testing.assert_allclose(spec_after.images[image_id].eop, image.eop, rtol=0,
                                   atol=POSE_ATOL)


def test_jaxba_import_warns_of_the_sensor_it_leaves_out(tmp_path):
    code, stdout, stderr = _run("import", "colmap", str(FIXTURE / "binary"), "--out",
                                str(tmp_path / "rig"))
    assert code == 0
    assert stderr == "jaxba: warning: rig 1: sensor IMU 1 left out: jaxba's rigs are of cameras\n"
    assert "rigs.toml" in stdout and "frames.txt" in stdout


@pytest.mark.parametrize("kind, suffix", [("text", "txt"), ("binary", "bin")])
def test_a_model_without_rigs_imports_as_before(kind, suffix, tmp_path):
    """Without rigs and frames (a model before COLMAP 3.12) no rigs.toml and no frames
    table, the images' poses images.txt's."""
    source = tmp_path / "legacy"
    source.mkdir()
    for name in ("cameras", "images", "points3D"):
        shutil.copy(FIXTURE / kind / f"{name}.{suffix}", source / f"{name}.{suffix}")
    written = write_colmap_project(source, tmp_path / "project", warn=pytest.fail)
    assert written.n_rigs == 0
    assert not (tmp_path / "project" / "rigs.toml").exists()
    assert "rigs" not in (tmp_path / "project" / "colmap.toml").read_text()
    spec = jaxba.read_project(written.project_file)
    assert spec.rigs == {} and spec.frames == {}
    for image in read_colmap_model(source).images.values():
        eop = colmap_pose_to_eop(image.qvec, image.tvec)
        np.testing.assert_allclose(spec.images[image.name].eop,
                                   np.r_[eop[:3], np.degrees(eop[3:])], rtol=0, atol=POSE_ATOL)


def _broken(tmp_path, name: str, edit) -> pathlib.Path:
    folder = tmp_path / "broken"
    shutil.copytree(FIXTURE / "text", folder)
    path = folder / name
    path.write_text(edit(path.read_text()))
    return folder


@pytest.mark.parametrize("name, edit, message", [
    ("frames.txt", lambda s: s.replace("\n5 2 ", "\n5 9 "), "frames.txt: frame 5: unknown rig 9"),
    ("frames.txt", lambda s: s.replace(" 1 CAMERA 3 8\n", " 1 CAMERA 1 8\n"),
     "frames.txt: frame 5: sensor CAMERA 1 is not in rig 2"),
    ("frames.txt", lambda s: s[:s.rindex("\n5 2 ")] + "\n",
     "images.txt: image 8 is in no frame of frames.txt"),
    ("rigs.txt", lambda s: s.replace("2 1 CAMERA 3", "2 1 CAMERA 7"),
     "rigs.txt: rig 2: unknown camera 7"),
    ("rigs.txt", lambda s: s.replace("2 1 CAMERA 3", "2 2 CAMERA 3"),
     r"rigs.txt:5: too few fields; expected RIG_ID NUM_SENSORS"),
    ("rigs.txt", lambda s: s.replace("IMU 1 1", "GPS 1 1"),
     "rigs.txt: rig 1: unknown sensor type 'GPS'; known: CAMERA, IMU"),
])
def test_rigs_that_do_not_fit_are_refused_naming_the_file(tmp_path, name, edit, message):
    with pytest.raises(ValueError, match=message):
        read_colmap_model(_broken(tmp_path, name, edit))


def test_a_broken_binary_file_is_refused_naming_it(tmp_path):
    folder = tmp_path / "binary"
    shutil.copytree(FIXTURE / "binary", folder)
    frames = folder / "frames.bin"
    frames.write_bytes(frames.read_bytes()[:-5])
    with pytest.raises(ValueError, match=r"frames.bin: ends inside frame record 5"):
        read_colmap_model(folder)
    cameras = folder / "cameras.bin"
    data = bytearray(cameras.read_bytes())
    data[12:16] = (7).to_bytes(4, "little")  # the first camera's model: FOV
    cameras.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="cameras.bin: camera 1: unsupported camera model "
                                         "number 7"):
        read_colmap_model(folder)


# --- out and back: a synthetic stereo rig -------------------------------------------------------


def _stereo_project(folder: pathlib.Path, seed: int = 5) -> pathlib.Path:
    """A stereo rig ("left" the reference, "right" at MOUNT) over board_scene's board from
    its stations: pixels through jaxba's opencv model plus N(0, NOISE_PX²); approximations
    the truth rounded; the right camera's pose in the rig computed from the images'."""
    rng = np.random.default_rng(seed)
    points, poses = board(), stations(rng)
    m_mount = opk_to_matrix(np.radians(MOUNT[3:]))
    right_poses = [(m_mount @ m, x0 + m.T @ MOUNT[:3]) for m, x0 in poses]
    folder.mkdir(parents=True)
    cameras = []
    for name, values in (("left", LEFT), ("right", RIGHT)):
        cameras += [f"[{name}]", 'model = "opencv"', "sensor = [640, 480]",
                    *(f"{k} = {v!r}" for k, v in values.items()), f"free = {json.dumps(FREE)}"]
    (folder / "cameras.toml").write_text("\n".join(cameras) + "\n")
    (folder / "points.txt").write_text("".join(
        f"{k + 1} {x!r} {y!r} {z!r} 0 0 0\n" for k, (x, y, z) in enumerate(points.tolist())))
    from jaxba._models._rotation_numpy import matrix_to_opk

    rows, observed, frames = [], [], []
    for name, values, camera_poses in (("left", LEFT, poses), ("right", RIGHT, right_poses)):
        for k, (uv, (m, x0)) in enumerate(zip(project(values, camera_poses, points),
                                              camera_poses)):
            image = f"{name}{k}"
            opk = np.degrees(matrix_to_opk(m))
            rows.append(f"{image} {name} " + " ".join(f"{v:.1f}" for v in x0) + " "
                        + " ".join(f"{v:.2f}" for v in opk))
            noisy = uv + rng.normal(scale=NOISE_PX, size=uv.shape)
            observed += [f"{image} {j + 1} {u!r} {v!r}" for j, (u, v) in enumerate(noisy.tolist())]
            frames.append(f"{image} pair{k}")
    project_file = write_pixel_project(folder, "stereo", rows, observed, NOISE_PX)
    (folder / "rigs.toml").write_text('[stereo]\nreference = "left"\n[stereo.right]\n')
    (folder / "frames.txt").write_text("\n".join(frames) + "\n")
    text = project_file.read_text().replace(
        "[files]", '[files]\nrigs = "rigs.toml"\nframes = "frames.txt"')
    project_file.write_text(text)
    return project_file


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    """The stereo project adjusted (`jaxba adjust`): (project file, its output folder)."""
    folder = tmp_path_factory.mktemp("colmap_rig")
    project_file = _stereo_project(folder / "stereo")
    code, _, stderr = _run("adjust", str(project_file), "--out", str(folder / "out"))
    assert code == 0, stderr
    return project_file, folder / "out"


@pytest.fixture(scope="module")
def exported(adjusted, tmp_path_factory):
    """The adjustment exported to COLMAP (`jaxba export --format colmap`)."""
    to = tmp_path_factory.mktemp("export") / "colmap"
    code, _, stderr = _run("export", str(adjusted[1]), "--format", "colmap", "--to", str(to))
    assert code == 0 and stderr == "", stderr
    return to


def test_the_export_writes_the_rig_and_imports_back_the_same(adjusted, exported, tmp_path):
    """rigs.txt and frames.txt beside the model; imported back (`jaxba import colmap`), the
    right camera's pose in the rig and every frame's pose are results.json's to 1e-9 (mm,
    degrees), the frames hold the same images."""
    results = json.loads((adjusted[1] / "results.json").read_text())
    assert sorted(p.name for p in exported.iterdir()) == [
        "cameras.txt", "export.json", "frames.txt", "images.txt", "points3D.txt", "rigs.txt"]
    code, _, stderr = _run("import", "colmap", str(exported), "--out", str(tmp_path / "back"))
    assert code == 0 and stderr == "", stderr
    spec = jaxba.read_project(tmp_path / "back" / f"{exported.name}.toml")
    ((rig_id, rig),) = spec.rigs.items()
    assert rig.reference == "1"  # "left", numbered by the export
    ((camera, mount),) = rig.mounts.items()
    assert camera == "2"
    expected = [results["rigs"]["stereo"]["right"][name]["value"] for name in EOP]
    np.testing.assert_allclose([mount.values[n] for n in EOP], expected, rtol=0,
                               atol=ROUND_TRIP_ATOL)

    image_frames = results["image_frames"]
    n_pairs = len(results["frames"])
    assert image_frames == {f"{side}{k}": f"pair{k}" for side in ("left", "right")
                            for k in range(n_pairs)}
    groups = {}
    for image, frame in spec.frames.items():
        groups.setdefault(frame, set()).add(image)
    assert sorted(map(sorted, groups.values())) == sorted(
        sorted(i for i, f in image_frames.items() if f == frame) for frame in results["frames"])
    for image in (i for i in spec.images.values() if i.camera == "1"):
        frame = results["frames"][image_frames[image.id]]
        np.testing.assert_allclose(image.eop, [frame[n]["value"] for n in EOP], rtol=0,
                                   atol=ROUND_TRIP_ATOL)


def test_write_colmap_of_the_project_is_the_cli_export(adjusted, exported, tmp_path):
    """The library's export of the adjusted project (`write_colmap` with the adjusted
    parameters) has the CLI export's rigs and frames: the same adjustment, one from its
    parameters, one from results.json, to rounding."""
    project = jaxba.build_project(jaxba.read_project(adjusted[0]))
    result = jaxba.adjust_project(project)
    model = write_colmap(project, tmp_path, result.parameters)
    cli = read_colmap_model(exported)
    assert read_colmap_model(tmp_path) == model
    assert [rig.reference for rig in model.rigs.values()] == [
        rig.reference for rig in cli.rigs.values()]
    (((_, (q, t)),),) = (rig.sensors for rig in model.rigs.values() if rig.sensors)
    (((_, (q_cli, t_cli)),),) = (rig.sensors for rig in cli.rigs.values() if rig.sensors)
    np.testing.assert_allclose(q, q_cli, rtol=0, atol=POSE_ATOL)
    np.testing.assert_allclose(t, t_cli, rtol=0, atol=ROUND_TRIP_ATOL)
    assert [f.data for f in model.frames.values()] == [f.data for f in cli.frames.values()]
    for frame, frame_cli in zip(model.frames.values(), cli.frames.values()):
        np.testing.assert_allclose(frame.qvec, frame_cli.qvec, rtol=0, atol=POSE_ATOL)
        np.testing.assert_allclose(frame.tvec, frame_cli.tvec, rtol=0, atol=ROUND_TRIP_ATOL)


def test_pycolmap_reads_the_export_as_the_same_rig(adjusted, exported):
    """pycolmap's Reconstruction(export): every image's cam_from_world (composed by COLMAP
    from its frame's rig_from_world and its sensor_from_rig) is results.json's image pose,
    and the sensor_from_rig of the right camera is the relative pose of the two images of
    each frame, from results.json's image poses alone."""
    pycolmap = pytest.importorskip("pycolmap")
    results = json.loads((adjusted[1] / "results.json").read_text())
    reconstruction = pycolmap.Reconstruction(str(exported))
    assert reconstruction.num_rigs() == 1 and reconstruction.num_frames() == len(
        set(results["image_frames"].values()))
    for image in reconstruction.images.values():
        cam_from_world = image.cam_from_world()
        rotation, translation = _cam_from_world(_pose(results["images"][image.name]))
        np.testing.assert_allclose(cam_from_world.rotation.matrix(), rotation, atol=POSE_ATOL)
        np.testing.assert_allclose(cam_from_world.translation, translation, rtol=0, atol=1e-9)
    (rig,) = reconstruction.rigs.values()
    sensor = pycolmap.sensor_t(type=pycolmap.SensorType.CAMERA, id=2)
    sensor_from_rig = rig.sensor_from_rig(sensor)
    for k in range(len(results["frames"])):
        r_left, t_left = _cam_from_world(_pose(results["images"][f"left{k}"]))
        r_right, t_right = _cam_from_world(_pose(results["images"][f"right{k}"]))
        np.testing.assert_allclose(sensor_from_rig.rotation.matrix(), r_right @ r_left.T,
                                   atol=1e-9)
        np.testing.assert_allclose(sensor_from_rig.translation,
                                   t_right - r_right @ r_left.T @ t_left, rtol=0, atol=1e-9)


def test_a_results_json_without_image_frames_is_refused(adjusted, tmp_path):
    """A results.json of a jaxba before "image_frames": the rigs cannot be exported."""
    out = tmp_path / "out"
    out.mkdir()
    shutil.copy(adjusted[1] / "observations.csv", out)
    results = json.loads((adjusted[1] / "results.json").read_text())
    del results["image_frames"]
    (out / "results.json").write_text(json.dumps(results))
    code, _, stderr = _run("export", str(out), "--format", "colmap")
    assert code == 2 and 'no "image_frames"' in stderr and "adjust the project again" in stderr
    assert not (out / "export").exists()


def test_an_export_without_rigs_removes_the_earlier_exports_rig_files(adjusted, exported,
                                                                      tmp_path):
    """Into the folder of an earlier export with rigs, an export without them leaves no
    rigs.txt or frames.txt behind (COLMAP would put the new images into the old frames)."""
    to, out = tmp_path / "colmap", tmp_path / "out"
    shutil.copytree(exported, to)
    out.mkdir()
    shutil.copy(adjusted[1] / "observations.csv", out)
    results = json.loads((adjusted[1] / "results.json").read_text())
    del results["rigs"]
    (out / "results.json").write_text(json.dumps(results))
    code, _, stderr = _run("export", str(out), "--format", "colmap", "--to", str(to))
    assert code == 0 and stderr == "", stderr
    assert sorted(p.name for p in to.iterdir()) == [
        "cameras.txt", "export.json", "images.txt", "points3D.txt"]
    assert read_colmap_model(to).frames == {}
