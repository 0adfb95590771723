"""rigs.toml and the frames table (docs/project-files.md, "Rigs"): what the readers accept and
how they refuse what they cannot use, naming the file, line and key; and the blocks a project
with rigs builds (one pose per frame, one relative pose per rig camera)."""

import numpy as np
import pytest

import jaxba


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """The synthetic block's files (8 images alternating cameras C1, C2) to add rigs to."""
    folder = tmp_path_factory.mktemp("block")
    truth = jaxba.write_synthetic_project(folder, seed=3, n_images=8, n_targets=30,
                                          n_cameras=2)
    return truth.project_file


def _with_rigs(tmp_path, project, rigs: str, frames: str | None):
    """A copy of `project` whose [files] name rigs.toml (and frames.txt unless None)."""
    import shutil

    for path in project.parent.iterdir():
        shutil.copy(path, tmp_path / path.name)
    (tmp_path / "rigs.toml").write_text(rigs)
    lines = ['rigs = "rigs.toml"']
    if frames is not None:
        (tmp_path / "frames.txt").write_text(frames)
        lines.append('frames = "frames.txt"')
    text = (tmp_path / project.name).read_text()
    (tmp_path / project.name).write_text(text.replace("[files]", "[files]\n" + "\n".join(lines)))
    return tmp_path / project.name


PAIRS = "img01 f1\nimg02 f1\nimg03 f2\nimg04 f2\n"
RIG = ('[head]\nreference = "C1"\n[head.C2]\nX0 = 0.3\n'
       'free = ["X0", "Y0", "Z0", "omega", "phi", "kappa"]\n')


def test_frames_and_mounts_are_built(block, tmp_path):
    """Four images in two frames and four alone: six frames; the reference's identity and
    C2's pose in the rig; every image's rows; C2's pose X0 as given, the rest from the
    images' approximations (their mean relative pose over f1, f2)."""
    spec = jaxba.read_project(_with_rigs(tmp_path, block, RIG, PAIRS))
    assert spec.frames == {"img01": "f1", "img02": "f1", "img03": "f2", "img04": "f2"}
    project = jaxba.build_project(spec)
    layout = project.rigs
    assert layout.frame_ids == ["f1", "f2", "img05", "img06", "img07", "img08"]
    assert layout.mount_ids == ["reference", "head/C2"]
    np.testing.assert_array_equal(layout.image_frame, [0, 0, 1, 1, 2, 3, 4, 5])
    np.testing.assert_array_equal(layout.image_mount, [0, 1, 0, 1, 0, 1, 0, 1])
    assert project.problem.initial.mounts.shape == (2, 6)
    assert layout.mounts[1, 0] == 0.3
    assert project.problem.free.mounts.tolist() == [[False] * 6, [True] * 6]
    eop = {iid: np.array(image.eop) for iid, image in spec.images.items()}
    from jaxba._models._rotation_numpy import opk_to_matrix

    m1 = opk_to_matrix(np.radians(eop["img01"][3:]))
    m3 = opk_to_matrix(np.radians(eop["img03"][3:]))
    centres = [m1 @ (eop["img02"][:3] - eop["img01"][:3]),
               m3 @ (eop["img04"][:3] - eop["img03"][:3])]
    np.testing.assert_allclose(layout.mounts[1, 1:3], np.mean(centres, axis=0)[1:])
    # The frame of a reference image is that image's pose.
    np.testing.assert_allclose(layout.frames[0, :3], eop["img01"][:3])
    assert "mount head/C2 X0" in project.labels


@pytest.mark.parametrize("rigs, frames, message", [
    ('[head]\nreference = "C9"\n', None, "rigs.toml: [head]: unknown camera 'C9'"),
    ('[head]\nreference = "C1"\n[head.C2]\nfree = ["X1"]\n', None, "[head.C2] free"),
    ('[a]\nreference = "C1"\n[b]\nreference = "C1"\n', None, "already in rig 'a'"),
    ('[head]\nreference = "C1"\n[head.C1]\n', None, "reference camera has no pose"),
    ('[head]\nreference = "C1"\n[head.C2]\nX0 = "x"\n', None, "[head.C2] X0: expected a number"),
    (RIG, "img01 f1\nimg99 f1\n", "frames.txt:2: column image_id: unknown image 'img99'"),
    (RIG, "img01 f1\nimg03 f1\n", "frames.txt:2: column frame_id: frame 'f1' already has an"),
    (RIG, "img01 f1\nimg01 f2\n", "already in frame 'f1'"),
    (RIG, "img01 img02\n", "frame ID 'img02' is also the ID of an image"),
    ('[head]\nreference = "C1"\n', "img02 f1\n", "camera 'C2', which is in no rig"),
])
def test_bad_rigs_and_frames_are_refused(block, tmp_path, rigs, frames, message):
    with pytest.raises(jaxba.ProjectError) as error:
        jaxba.read_project(_with_rigs(tmp_path, block, rigs, frames))
    assert message in str(error.value)


def test_frames_need_rigs(block, tmp_path):
    path = _with_rigs(tmp_path, block, RIG, PAIRS)
    path.write_text(path.read_text().replace('rigs = "rigs.toml"\n', ""))
    with pytest.raises(jaxba.ProjectError, match="frames need rigs"):
        jaxba.read_project(path)


def test_a_rig_cameras_observed_pose_is_refused(block, tmp_path):
    """GNSS/INS σ on a non-reference rig camera's image: its pose is no unknown of its own."""
    path = _with_rigs(tmp_path, block, RIG, PAIRS)
    images = path.parent / "orientation.txt"
    lines = images.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("img02"))
    lines[k] += " 0.05 0.05 0.05 - - -"
    images.write_text("\n".join(lines) + "\n")
    with pytest.raises(jaxba.ProjectError, match="img02.*rig camera 'C2'.*reference camera"):
        jaxba.build_project(jaxba.read_project(path))


def _with_platform(tmp_path, project, mount: str):
    """A copy of `project` whose camera C1 has the `[C1.mount]` table `mount`."""
    import shutil

    for path in project.parent.iterdir():
        shutil.copy(path, tmp_path / path.name)
    cameras = tmp_path / "cameras.toml"
    cameras.write_text(cameras.read_text().replace("[C2]", mount + "\n[C2]"))
    return tmp_path / project.name


def test_a_platform_camera_is_the_body_then_its_mount(block, tmp_path):
    """`[C1.mount]`: C1's images are frames of their own holding the images table's values
    (the body's pose), followed by the lever arm and boresight (degrees read as radians);
    with both 0 the residuals are those of the project without the mount."""
    mount = ('[C1.mount]\nlever_arm = [0.1, -0.2, 0.3]\nboresight = [0.5, 0.0, -0.25]\n'
             'free = ["boresight"]\n[C1.mount.sigma]\nlever_arm = 0.01\n')
    project = jaxba.build_project(jaxba.read_project(_with_platform(tmp_path, block, mount)))
    layout = project.rigs
    assert layout.mount_ids == ["reference", "platform/C1"]
    np.testing.assert_allclose(layout.mounts[1], [0.1, -0.2, 0.3, *np.radians([0.5, 0, -0.25])])
    assert project.problem.free.mounts.tolist()[1] == [True] * 6  # weighted and free
    assert any(g.name == "mount_priors" for g in project.problem.groups)
    spec = project.spec
    np.testing.assert_allclose(layout.frames[0, :3], spec.images["img01"].eop[:3])
    np.testing.assert_array_equal(layout.image_mount, [1, 0] * 4)
    plain = jaxba.build_project(jaxba.read_project(block)).problem
    (tmp_path / "zero").mkdir()
    zero = _with_platform(tmp_path / "zero", block, "[C1.mount]\n")
    zero = jaxba.build_project(jaxba.read_project(zero)).problem
    np.testing.assert_allclose(np.asarray(zero.whitened(zero.initial)[0]),
                               np.asarray(plain.whitened(plain.initial)[0]), rtol=0, atol=1e-9)


@pytest.mark.parametrize("mount, message", [
    ("[C1.mount]\nlever_arm = [0.1, 0.2]\n", "[C1.mount] lever_arm: expected a list of three"),
    ('[C1.mount]\nfree = ["lever"]\n', "[C1.mount] free: expected a list of lever_arm"),
    ('[C1.mount]\nfree = ["boresight"]\n[C1.mount.sigma]\nboresight = 0.1\n',
     "'boresight' is also in free"),
    ("[C1.mount]\nheight = 2\n", "[C1.mount]: unknown key 'height'"),
])
def test_bad_platform_mounts_are_refused(block, tmp_path, mount, message):
    with pytest.raises(jaxba.ProjectError) as error:
        jaxba.read_project(_with_platform(tmp_path, block, mount))
    assert message in str(error.value)
