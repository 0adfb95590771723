"""Tests of the project readers: a minimal valid project, then one mutation per test."""

import pathlib

import pytest

from jaxba._io._project._readers import read_project, read_project_file, read_project_tables
from jaxba._project._errors import ProjectError
from jaxba._project._spec import AdjustmentSettings

PROJECT = """\
[project]
name = "lab1"
image_units = "mm"

[files]
cameras = "cameras.toml"
images = "orientation.txt"
image_points = "image_coordinates.txt"
points = "ground_points.txt"
distances = "distances.txt"

[adjustment]
sigma0 = 1.0
image_sigma = 0.002
max_iterations = 20
"""

CAMERAS = """\
[C1]
model = "smac"
pixel_size = [0.00369, 0.00369]
sensor = [6000, 4000]
c = 8.5
K1 = 1e-4
free = ["xp", "yp", "c", "K1"]
[C1.sigma]
K2 = 1e-6
"""

# Line numbers matter: the tests below refer to them.
IMAGES = """\
# image camera X0 Y0 Z0 omega phi kappa [sX0 sY0 sZ0 somega sphi skappa]
img1 C1  0.0 0.0 10.0  0.0 0.0  90.0
img2 C1  5.0 0.0 10.0  1.5 -2.0 90.0  0.05 0.05 0.1 - 0 -   # GNSS position
"""

POINTS = """\
# id  X     Y     Z    sX   sY   sZ

P1   0.0   0.0   0.0  0    0    0
P2  10.0   0.0   0.0  0.01 0.01 -
P3  10.0  10.0   0.5  -    -    -
T1   5.0   5.0   0.1
T2   2.0   8.0   0.2  # a tie point, σ columns left out
"""

IMAGE_POINTS = """\
# image point x y [sx sy]
img1 P1 -1.0  1.0
img1 P2  1.0  1.0  0.003 0.004
img1 P3  1.0 -1.0  - -
img1 T1  0.1  0.1
img1 T2  0.2  0.2

img2 P1 -2.0  1.0
img2 P2  0.5  1.0
img2 P3  0.5 -1.0
img2 T1 -0.4  0.1
img2 T2 -0.3  0.2   # trailing comment
"""

DISTANCES = """\
P1 P2 10.001 0.001
"""

DEFAULTS = {
    "lab1.toml": PROJECT,
    "cameras.toml": CAMERAS,
    "orientation.txt": IMAGES,
    "ground_points.txt": POINTS,
    "image_coordinates.txt": IMAGE_POINTS,
    "distances.txt": DISTANCES,
}


def write_project(tmp_path: pathlib.Path, **replace: tuple[str, str]) -> pathlib.Path:
    """Write the minimal project; `file_name=(old, new)` replaces text in one file first.

    Keyword names are the file names with '.' -> '_' (e.g. `ground_points_txt`).
    """
    texts = dict(DEFAULTS)
    for key, (old, new) in replace.items():
        name = next(name for name in texts if name.replace(".", "_") == key)
        assert old in texts[name], f"{old!r} not in {name}"
        texts[name] = texts[name].replace(old, new, 1)
    for name, text in texts.items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    return tmp_path / "lab1.toml"


def error_of(path: pathlib.Path) -> str:
    """The message of the ProjectError that reading `path` raises."""
    with pytest.raises(ProjectError) as info:
        read_project(path)
    return str(info.value)


def assert_error(path: pathlib.Path, *parts: str) -> None:
    """Reading `path` raises a ProjectError whose message contains every part."""
    message = error_of(path)
    for part in parts:
        assert part in message, f"{part!r} not in {message!r}"


# --- a valid project --------------------------------------------------------------------


def test_valid_project(tmp_path):
    spec = read_project(write_project(tmp_path))
    assert spec.name == "lab1"
    assert spec.image_units == "mm"
    assert spec.path == (tmp_path / "lab1.toml").resolve()
    assert spec.complete and not spec.missing_images and not spec.missing_points
    assert spec.file_names["points"] == "ground_points.txt"
    assert spec.files["points"] == (tmp_path / "ground_points.txt").resolve()
    assert spec.settings == AdjustmentSettings(sigma0=1.0, image_sigma=0.002, max_iterations=20)

    camera = spec.cameras["C1"]
    assert camera.model == "smac"
    assert camera.values["c"] == 8.5 and camera.values["K1"] == 1e-4
    assert camera.values["K2"] == 0.0 and camera.values["A2"] == 0.0  # left out -> 0
    assert camera.free == frozenset({"xp", "yp", "c", "K1"})
    assert camera.sigma == {"K2": 1e-6}
    assert camera.pixel_size == (0.00369, 0.00369)
    assert camera.sensor == (6000, 4000)

    assert list(spec.images) == ["img1", "img2"]
    img1, img2 = spec.images["img1"], spec.images["img2"]
    assert img1.camera == "C1" and img1.line == 2
    assert img1.eop == (0.0, 0.0, 10.0, 0.0, 0.0, 90.0)  # angles stay in degrees
    assert img1.eop_sigma == (None,) * 6
    assert img2.eop == (5.0, 0.0, 10.0, 1.5, -2.0, 90.0)
    assert img2.eop_sigma == (0.05, 0.05, 0.1, None, 0.0, None)

    assert list(spec.points) == ["P1", "P2", "P3", "T1", "T2"]
    assert spec.points["P1"].sigma == (0.0, 0.0, 0.0)
    assert spec.points["P2"].sigma == (0.01, 0.01, None)
    assert spec.points["P2"].xyz == (10.0, 0.0, 0.0)
    assert spec.points["P3"].sigma == (None, None, None)
    assert spec.points["T1"].sigma == (None, None, None)
    assert spec.points["T2"].line == 7

    assert len(spec.image_points) == 10
    first, second, third = spec.image_points[:3]
    assert (first.image, first.point, first.xy, first.sigma) == ("img1", "P1", (-1.0, 1.0), None)
    assert second.sigma == (0.003, 0.004)
    assert third.sigma is None and third.line == 4
    assert spec.image_points[-1].line == 12

    (distance,) = spec.distances
    assert (distance.a, distance.b, distance.distance, distance.sigma) == (
        "P1",
        "P2",
        10.001,
        0.001,
    )
    assert distance.line == 1

    assert set(spec.input_files) == {(tmp_path / name).resolve() for name in DEFAULTS}


def test_defaults_name_units_model_and_no_distances(tmp_path):
    path = write_project(
        tmp_path,
        lab1_toml=('name = "lab1"\nimage_units = "mm"\n', ""),
        cameras_toml=('model = "smac"\n', ""),
    )
    text = path.read_text().replace('distances = "distances.txt"\n', "")
    text = text.replace(
        "[adjustment]\nsigma0 = 1.0\nimage_sigma = 0.002\nmax_iterations = 20\n", ""
    )
    path.write_text(text)
    spec = read_project(path)
    assert spec.name == "lab1"  # the file stem
    assert spec.image_units == "mm"
    assert spec.settings == AdjustmentSettings()
    assert spec.cameras["C1"].model == "smac"
    assert spec.distances == []
    assert (tmp_path / "distances.txt").resolve() not in spec.input_files


def test_all_adjustment_keys(tmp_path):
    settings = """[adjustment]
sigma0 = 2
image_sigma = 0.5
max_iterations = 7
variance_components = true
rtol = 0.0
atol = 1e-8
refraction = true
object_unit_km = 1e-6
height_offset = -12.5
"""
    path = write_project(tmp_path)
    path.write_text(path.read_text().split("[adjustment]")[0] + settings)
    assert read_project(path).settings == AdjustmentSettings(
        sigma0=2.0,
        image_sigma=0.5,
        max_iterations=7,
        variance_components=True,
        rtol=0.0,
        atol=1e-8,
        refraction=True,
        object_unit_km=1e-6,
        height_offset=-12.5,
    )


def test_paths_relative_to_project_file(tmp_path, monkeypatch):
    (tmp_path / "project").mkdir()
    write_project(tmp_path / "project")
    monkeypatch.chdir(tmp_path)
    spec = read_project(pathlib.Path("project") / "lab1.toml")
    assert len(spec.points) == 5


def test_comments_blank_lines_crlf_and_bom(tmp_path):
    path = write_project(tmp_path)
    points = "\ufeff" + POINTS.replace("\n", "\r\n") + "\r\n   \r\n# the end\r\n"
    (tmp_path / "ground_points.txt").write_text(points, encoding="utf-8", newline="")
    spec = read_project(path)
    assert list(spec.points) == ["P1", "P2", "P3", "T1", "T2"]
    assert spec.points["T2"].line == 7


def test_unused_point_and_unused_camera_are_kept(tmp_path):
    path = write_project(
        tmp_path,
        ground_points_txt=("T2 ", "U9   1.0   2.0   3.0  - - -\nT2 "),
        cameras_toml=("[C1.sigma]", "[C2]\nc = 35.0\n[C1.sigma]"),
    )
    spec = read_project(path)
    assert "U9" in spec.points
    assert spec.points["T2"].line == 8
    assert set(spec.cameras) == {"C1", "C2"}


def test_weighted_point_in_one_image_is_allowed(tmp_path):
    # P2 has σ (weighted/fixed) in all three coordinates: one ray is enough.
    path = write_project(
        tmp_path,
        ground_points_txt=("0.01 0.01 -", "0.01 0.01 0.02"),
        image_coordinates_txt=("img2 P2  0.5  1.0\n", ""),
    )
    assert len(read_project(path).image_points) == 9


def test_pixel_units(tmp_path):
    path = write_project(tmp_path, lab1_toml=('"mm"', '"pixel"'))
    spec = read_project(path)
    assert spec.image_units == "pixel"
    assert spec.image_points[1].sigma == (0.003, 0.004)  # not converted: in pixels


# --- the project file -------------------------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "parts"),
    [
        ('"mm"', '"inch"', ["lab1.toml", "image_units", "'inch'"]),
        (
            "max_iterations = 20",
            "max_iteration = 20",
            ["lab1.toml", "[adjustment]", "'max_iteration'", "max_iterations"],
        ),
        (
            'name = "lab1"',
            'name = "lab1"\ntitle = "x"',
            ["lab1.toml", "[project]", "'title'", "image_units"],
        ),
        (
            'points = "ground_points.txt"',
            'point = "ground_points.txt"',
            ["lab1.toml", "[files]", "'point'"],
        ),
        ("[adjustment]", "[adjustmnet]", ["lab1.toml", "'adjustmnet'", "adjustment"]),
        ("sigma0 = 1.0", 'sigma0 = "1"', ["lab1.toml", "sigma0", "'1'"]),
        ("sigma0 = 1.0", "sigma0 = -1.0", ["lab1.toml", "sigma0", "> 0", "-1.0"]),
        ("image_sigma = 0.002", "image_sigma = 0", ["lab1.toml", "image_sigma", "> 0"]),
        ("image_sigma = 0.002", "image_sigma = nan", ["lab1.toml", "image_sigma", "nan"]),
        ("max_iterations = 20", "max_iterations = 2.5", ["lab1.toml", "max_iterations", "integer"]),
        (
            "max_iterations = 20",
            "max_iterations = 0",
            ["lab1.toml", "max_iterations", "integer > 0"],
        ),
        (
            "max_iterations = 20",
            "variance_components = 1",
            ["lab1.toml", "variance_components", "true or false"],
        ),
        ("max_iterations = 20", "rtol = -1e-3", ["lab1.toml", "rtol", "≥ 0"]),
        ("sigma0 = 1.0", "sigma0 = true", ["lab1.toml", "sigma0", "True"]),
        ('name = "lab1"', 'name = "../lab1"', ["lab1.toml", "[project] name"]),
        ('name = "lab1"', "name = 3", ["lab1.toml", "[project] name", "string"]),
        ('name = "lab1"', "name = ", ["lab1.toml", "invalid TOML", "line 2"]),
    ],
)
def test_project_file_errors(tmp_path, old, new, parts):
    path = write_project(tmp_path, lab1_toml=(old, new))
    assert_error(path, *parts)
    with pytest.raises(ProjectError) as info:  # the project file alone: the same error
        read_project_file(path)
    assert str(info.value) == error_of(path)


def test_project_file_without_the_tables(tmp_path):
    """`read_project_file` gives `read_project`'s name and input files from the project file
    alone (a table that cannot be read does not stop it), and `read_project_tables` of it
    is `read_project`'s project, or its error."""
    path = write_project(tmp_path)
    spec = read_project(path)
    head = read_project_file(path)
    assert (head.name, head.input_files) == (spec.name, spec.input_files)
    assert len(spec.input_files) == 1 + len(spec.files)
    assert read_project_tables(head) == spec
    (tmp_path / "ground_points.txt").write_text("P1 1 2\n")  # one column short
    head = read_project_file(path)
    assert (head.name, head.input_files) == (spec.name, spec.input_files)
    assert_error(path, "ground_points.txt:1")
    with pytest.raises(ProjectError) as info:
        read_project_tables(head)
    assert str(info.value) == error_of(path)


def test_missing_files_key(tmp_path):
    path = write_project(tmp_path, lab1_toml=('points = "ground_points.txt"\n', ""))
    assert_error(path, "lab1.toml", "[files] points", "missing")


def test_missing_files_table(tmp_path):
    path = write_project(tmp_path)
    path.write_text('[project]\nname = "x"\n')
    assert_error(path, "lab1.toml", "[files]")


def test_missing_file(tmp_path):
    path = write_project(tmp_path, lab1_toml=('"ground_points.txt"', '"data/gcp.txt"'))
    assert_error(
        path, "lab1.toml", "[files] points", str((tmp_path / "data" / "gcp.txt").resolve())
    )


def test_missing_project_file(tmp_path):
    assert_error(tmp_path / "nothing.toml", "nothing.toml")


# --- cameras.toml -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "parts"),
    [
        (
            'model = "smac"',
            'model = "fisheye9"',
            ["cameras.toml", "[C1] model", "'fisheye9'", "smac"],
        ),
        ("K1 = 1e-4", "K9 = 1e-4", ["cameras.toml", "[C1]", "'K9'", "xp, yp, c, K0"]),
        ('"K1"]', '"K1", "k2"]', ["cameras.toml", "[C1] free", "'k2'", "xp, yp, c, K0"]),
        ('free = ["xp", "yp", "c", "K1"]', 'free = "c"', ["cameras.toml", "[C1] free", "list"]),
        ("K2 = 1e-6", "Q2 = 1e-6", ["cameras.toml", "[C1.sigma]", "'Q2'", "xp, yp, c, K0"]),
        ("K2 = 1e-6", "c = 0.01", ["cameras.toml", "[C1.sigma] c", "free"]),
        ("K2 = 1e-6", "K2 = 0.0", ["cameras.toml", "[C1.sigma] K2", "> 0"]),
        ("K2 = 1e-6", "K2 = -1e-6", ["cameras.toml", "[C1.sigma] K2", "> 0"]),
        ("c = 8.5", 'c = "8.5"', ["cameras.toml", "[C1] c", "number"]),
        (
            "c = 8.5",
            "c = 8.5\nr0 = 12.5",
            ["cameras.toml", "[C1] r0", "constant of model 'metrology'", "model 'smac' has no r0"],
        ),
        ("c = 8.5", "c = inf", ["cameras.toml", "[C1] c", "number"]),
        (
            "pixel_size = [0.00369, 0.00369]",
            "pixel_size = 0.00369",
            ["cameras.toml", "[C1] pixel_size", "two"],
        ),
        (
            "pixel_size = [0.00369, 0.00369]",
            "pixel_size = [0.00369, 0]",
            ["cameras.toml", "[C1] pixel_size", "> 0"],
        ),
        (
            "sensor = [6000, 4000]",
            "sensor = [6000.5, 4000]",
            ["cameras.toml", "[C1] sensor", "integer"],
        ),
        ("[C1]\n", "version = 2\n[C1]\n", ["cameras.toml", "version", "table"]),
        ("[C1]\n", "[C1\n", ["cameras.toml", "invalid TOML"]),
    ],
)
def test_camera_errors(tmp_path, old, new, parts):
    assert_error(write_project(tmp_path, cameras_toml=(old, new)), *parts)


METROLOGY_CAMERAS = """\
[C1]
model = "metrology"
r0 = 12.5
c = 24.5
A1 = -1e-4
free = ["xh", "yh", "c", "A1"]
[C1.sigma]
C1 = 1e-4
"""


def test_metrology_camera_and_its_constant_r0(tmp_path):
    spec = read_project(write_project(tmp_path, cameras_toml=(CAMERAS, METROLOGY_CAMERAS)))
    camera = spec.cameras["C1"]
    assert camera.model == "metrology"
    assert camera.constants == {"r0": 12.5}
    assert camera.values == {"xh": 0.0, "yh": 0.0, "c": 24.5, "A1": -1e-4, "A2": 0.0, "A3": 0.0,
                             "B1": 0.0, "B2": 0.0, "C1": 0.0, "C2": 0.0}
    assert camera.free == frozenset({"xh", "yh", "c", "A1"}) and camera.sigma == {"C1": 1e-4}
    assert read_project(write_project(tmp_path)).cameras["C1"].constants == {}


@pytest.mark.parametrize(
    ("old", "new", "parts"),
    [
        ("r0 = 12.5\n", "", ["cameras.toml", "[C1] r0", "missing", "'metrology'"]),
        ("r0 = 12.5", "r0 = -1.0", ["cameras.toml", "[C1] r0", "≥ 0"]),
        ("r0 = 12.5", 'r0 = "12.5"', ["cameras.toml", "[C1] r0", "number"]),
        ('"A1"]', '"A1", "r0"]', ["cameras.toml", "[C1] free", "'r0'", "constant", "cannot"]),
        ("C1 = 1e-4", "r0 = 0.1", ["cameras.toml", "[C1.sigma] r0", "constant", "no prior"]),
        ("c = 24.5", "c = 0.0", ["cameras.toml", "[C1] c", "> 0"]),
    ],
)
def test_metrology_camera_errors(tmp_path, old, new, parts):
    cameras = METROLOGY_CAMERAS.replace(old, new, 1)
    assert_error(write_project(tmp_path, cameras_toml=(CAMERAS, cameras)), *parts)


@pytest.mark.parametrize("key", ["pixel_size", "sensor"])
def test_pixel_units_need_pixel_size_and_sensor(tmp_path, key):
    line = next(line for line in CAMERAS.splitlines() if line.startswith(key))
    path = write_project(tmp_path, lab1_toml=('"mm"', '"pixel"'), cameras_toml=(line + "\n", ""))
    assert_error(path, "cameras.toml", "[C1]", key, "pixel")


# --- text tables ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("old", "new", "parts"),
    [
        (
            "img1 C1  0.0 0.0 10.0  0.0 0.0  90.0",
            "img1 C1  0.0 0.0 10.0  0.0 0.0",
            ["orientation.txt:2:", "8 or 14 columns", "got 7"],
        ),
        (
            "0.05 0.05 0.1 - 0 -",
            "0.05 0.05 0.1 - 0",
            ["orientation.txt:3:", "8 or 14 columns", "got 13"],
        ),
        ("img1 C1  0.0", "img1 C1  O.0", ["orientation.txt:2:", "column X0", "'O.0'"]),
        ("1.5 -2.0 90.0", "1.5 nan 90.0", ["orientation.txt:3:", "column phi", "'nan'"]),
        ("1.5 -2.0 90.0", "1.5 -2.0 inf", ["orientation.txt:3:", "column kappa", "'inf'"]),
        ("0.05 0.05 0.1", "0.05 -0.05 0.1", ["orientation.txt:3:", "column sY0", "'-0.05'"]),
        ("- 0 -   #", "- 0 abc #", ["orientation.txt:3:", "column skappa", "'abc'"]),
        ("img2 C1", "img2 C9", ["orientation.txt:3:", "column camera_id", "'C9'", "cameras.toml"]),
        ("img2 C1", "img1 C1", ["orientation.txt:3:", "duplicate image 'img1'", "line 2"]),
    ],
)
def test_image_table_errors(tmp_path, old, new, parts):
    assert_error(write_project(tmp_path, orientation_txt=(old, new)), *parts)


def test_empty_image_table(tmp_path):
    path = write_project(tmp_path)
    (tmp_path / "orientation.txt").write_text("# nothing yet\n")
    assert_error(path, "orientation.txt", "no images")


@pytest.mark.parametrize(
    ("old", "new", "parts"),
    [
        (
            "0.01 0.01 -",
            "0.01 0.01 abc",
            ["ground_points.txt:4: column sZ: expected a number, '0' or '-', got 'abc'"],
        ),
        ("0.01 0.01 -", "0.01 -0.01 -", ["ground_points.txt:4:", "column sY", "'-0.01'"]),
        ("0.01 0.01 -", "0.01 0.01", ["ground_points.txt:4:", "4 or 7 columns", "got 6"]),
        ("P3  10.0", "P3  1O.0", ["ground_points.txt:5:", "column X", "'1O.0'"]),
        ("0.0  0    0    0", "NaN  0    0    0", ["ground_points.txt:3:", "column Z", "'NaN'"]),
        ("T2 ", "P1 ", ["ground_points.txt:7:", "duplicate point 'P1'", "line 3"]),
    ],
)
def test_point_table_errors(tmp_path, old, new, parts):
    assert_error(write_project(tmp_path, ground_points_txt=(old, new)), *parts)


@pytest.mark.parametrize(
    ("old", "new", "parts"),
    [
        (
            "img1 P1 -1.0  1.0",
            "img1 P1 -1.0",
            ["image_coordinates.txt:2:", "4 or 6 columns", "got 3"],
        ),
        ("0.003 0.004", "0.003", ["image_coordinates.txt:3:", "4 or 6 columns", "got 5"]),
        ("img1 P1 -1.0", "img1 P1 -1.0.0", ["image_coordinates.txt:2:", "column x", "'-1.0.0'"]),
        ("0.003 0.004", "0.003 0", ["image_coordinates.txt:3:", "column sy", "> 0"]),
        ("0.003 0.004", "0.003 -", ["image_coordinates.txt:3:", "column sy", "both"]),
        ("0.003 0.004", "0.003 -0.004", ["image_coordinates.txt:3:", "column sy", "'-0.004'"]),
        (
            "img1 T1",
            "img9 T1",
            ["image_coordinates.txt:5:", "unknown image 'img9'", "orientation.txt"],
        ),
        (
            "img2 T2",
            "img2 T1",
            ["image_coordinates.txt:12:", "point 'T1'", "image 'img2'", "line 11"],
        ),
    ],
)
def test_image_point_table_errors(tmp_path, old, new, parts):
    assert_error(write_project(tmp_path, image_coordinates_txt=(old, new)), *parts)


@pytest.mark.parametrize(
    ("old", "new", "parts"),
    [
        ("10.001 0.001", "10.001", ["distances.txt:1:", "4 columns", "got 3"]),
        ("10.001 0.001", "10.001 0", ["distances.txt:1:", "column sigma", "> 0"]),
        ("10.001 0.001", "10.001 -", ["distances.txt:1:", "column sigma", "'-'"]),
        ("10.001 0.001", "-10.001 0.001", ["distances.txt:1:", "column distance", "> 0"]),
        ("P1 P2", "P1 P9", ["distances.txt:1:", "column point_b", "'P9'", "ground_points.txt"]),
        ("P1 P2", "P2 P2", ["distances.txt:1:", "'P2'", "different"]),
    ],
)
def test_distance_table_errors(tmp_path, old, new, parts):
    assert_error(write_project(tmp_path, distances_txt=(old, new)), *parts)


# --- consistency ------------------------------------------------------------------------


def test_free_point_in_one_image(tmp_path):
    path = write_project(tmp_path, image_coordinates_txt=("img2 T1 -0.4  0.1\n", ""))
    assert_error(
        path,
        "ground_points.txt:6:",
        "point 'T1' is measured in only 1 image (img1) but has free coordinates",
    )


def test_partly_free_point_in_one_image(tmp_path):
    path = write_project(tmp_path, image_coordinates_txt=("img2 P2  0.5  1.0\n", ""))
    assert_error(path, "ground_points.txt:4:", "point 'P2'", "only 1 image (img1)")


def test_free_point_only_in_a_distance(tmp_path):
    path = write_project(
        tmp_path,
        ground_points_txt=("T2 ", "U9   1.0   2.0   3.0\nT2 "),
        distances_txt=("\n", "\nP1 U9 3.7 0.001\n"),
    )
    assert_error(path, "ground_points.txt:7:", "point 'U9'", "no image", "distances.txt:2")


# --- missing approximations -------------------------------------------------------------


def test_images_without_eops_and_points_without_approximation(tmp_path):
    """`-` in all six EOP columns, and tie points measured but absent from the points table,
    are read as missing approximations (None), the points appended in order of first
    measurement at that line; a distance may use such a point."""
    path = write_project(
        tmp_path,
        orientation_txt=("img1 C1  0.0 0.0 10.0  0.0 0.0  90.0", "img1 C1  - - -  - - -"),
        ground_points_txt=("T1   5.0   5.0   0.1\n", ""),
        image_coordinates_txt=("img2 T2 -0.3  0.2", "img2 T2 -0.3  0.2\nimg1 U1 0 0\nimg2 U1 1 1"),
        distances_txt=("\n", "\nU1 P1 3.0 0.01\n"),
    )
    spec = read_project(path)
    assert spec.images["img1"].eop is None and spec.images["img2"].eop is not None
    assert spec.missing_images == ["img1"]
    assert spec.missing_points == ["T1", "U1"] and not spec.complete
    assert list(spec.points)[-2:] == ["T1", "U1"]
    assert spec.points["T1"].xyz is None and spec.points["T1"].sigma == (None, None, None)
    assert (spec.points["T1"].line, spec.points["U1"].line) == (5, 13)
    assert spec.distances[-1].a == "U1"


@pytest.mark.parametrize(
    ("old", "new", "parts"),
    [
        ("img1 C1  0.0 0.0 10.0", "img1 C1  - - 10.0",
         ["orientation.txt:2:", "column Z0", "all six EOP columns"]),
        ("img1 C1  0.0 0.0 10.0  0.0 0.0  90.0", "img1 C1  0.0 0.0 10.0  - - -",
         ["orientation.txt:2:", "column omega", "or in none"]),
        ("img2 C1  5.0 0.0 10.0  1.5 -2.0 90.0", "img2 C1  - - - - - -",
         ["orientation.txt:3:", "column sX0", "weighted", "needs its value"]),
        ("img2 C1  5.0 0.0 10.0  1.5 -2.0 90.0  0.05 0.05 0.1 - 0 -",
         "img2 C1  - - - - - -  - - - - 0 -",
         ["orientation.txt:3:", "column sphi", "fixed"]),
    ],
)
def test_partial_or_constrained_missing_eops(tmp_path, old, new, parts):
    assert_error(write_project(tmp_path, orientation_txt=(old, new)), *parts)


def test_point_without_approximation_in_one_image(tmp_path):
    path = write_project(tmp_path, image_coordinates_txt=(
        "img1 T2  0.2  0.2\n", "img1 T2  0.2  0.2\nimg1 P7  0.3  0.3\n"))
    assert_error(path, "image_coordinates.txt:7:", "point 'P7'", "only 1 image (img1)",
                 "not in ground_points.txt")


def test_distance_to_an_unmeasured_unknown_point(tmp_path):
    path = write_project(tmp_path, distances_txt=("P1 P2", "P1 P7"))
    assert_error(path, "distances.txt:1:", "unknown point 'P7'", "ground_points.txt")


def test_image_without_measurements(tmp_path):
    path = write_project(tmp_path, orientation_txt=("img2 C1", "img3 C1 1 2 3 4 5 6\nimg2 C1"))
    assert_error(
        path, "orientation.txt:3:", "image 'img3'", "no measurements", "image_coordinates.txt"
    )
