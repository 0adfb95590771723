"""The flat port (`FlatPort`, cameras.toml `[ID.refraction]`) against an independent NumPy ray
tracer (Snell's law in vector form at both glass surfaces): projections over the whole sensor,
rays to object points (brentq), invalid geometry, derivatives against finite differences, and a
block simulated by the tracer adjusted through project files."""

import dataclasses
import math
import shutil

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import FD_ATOL, FD_RTOL, FD_STEP, central_difference
from scipy.optimize import brentq

import jaxba
from jaxba import advanced
from jaxba._io._synthetic import look_at, opk_from_rotation, smac_correction, solve_measured

IMAGE_ATOL = 1e-9  # image units (mm or pixels): the projection against the traced ray
RAY_ATOL = 1e-12  # rad: the port's ray against brentq's (both at the rounding level)
JACREV_RTOL = 1e-12  # reverse against forward mode: the same derivatives, other order of sums
SIGMA0_RANGE = (0.85, 1.15)  # σ̂0 of the simulated block: redundancy ~ 560, sd(σ̂0) ≈ 0.03
TRUTH_SIGMAS = 4.0  # adjusted parameters within this many of their σ of the truth

PORT = {"distance": 0.045, "thickness": 0.012, "n_air": 1.0, "n_glass": 1.49, "n_medium": 1.337}
TILTED = np.array([0.06, -0.04, -1.0])  # a port normal off the optical axis (camera frame)
NORMALS = {"axis": np.array([0.0, 0.0, -1.0]), "tilted": TILTED}
SMAC = {"xp": 0.012, "yp": -0.008, "c": 8.52, "K0": 0.0, "K1": -8.0e-4, "K2": 3.0e-6,
        "K3": -1.0e-8, "P1": 2.0e-5, "P2": -1.5e-5, "P3": 0.0, "A1": 0.0, "A2": 0.0}
SENSOR_MM = (22.14, 14.76)  # the format, mm: a corner 57° off the axis in air
CV_FROM_CAMERA = np.diag([1.0, -1.0, -1.0])


# --- the NumPy ray tracer ------------------------------------------------------------------


def _unit(v):
    return np.asarray(v, dtype=float) / np.linalg.norm(v)


def _port_normal(normal):
    """The unit normal turned towards the object (z < 0)."""
    normal = _unit(normal)
    return normal if normal[2] < 0 else -normal


def _refract(d, normal, n1, n2):
    """Snell's law in vector form: the unit direction `d` crossing a surface of unit normal
    `normal` (oriented along the travel) from index n1 to n2; None beyond the critical angle."""
    cos_i = d @ normal
    eta = n1 / n2
    k = 1.0 - eta**2 * (1.0 - cos_i**2)
    if k < 0:
        return None
    return eta * d + (math.sqrt(k) - eta * cos_i) * normal


def _trace(direction, port, normal):
    """The ray leaving the centre along `direction` (air): its exit point on the outer glass
    surface and its unit direction in the medium (None past a critical angle)."""
    axis = np.array([0.0, 0.0, -1.0])
    d = _unit(direction)
    inner = port["distance"] * (normal @ axis)  # perpendicular distance of the inner surface
    p1 = d * inner / (d @ normal)
    d2 = _refract(d, normal, port["n_air"], port["n_glass"])
    if d2 is None:
        return None, None
    p2 = p1 + d2 * port["thickness"] / (d2 @ normal)
    d3 = _refract(d2, normal, port["n_glass"], port["n_medium"])
    return p2, d3


def _point_at_depth(direction, port, normal, depth):
    """The object point on the traced ray at depth `depth` along the normal."""
    p2, d3 = _trace(direction, port, normal)
    return p2 + d3 * (depth - p2 @ normal) / (d3 @ normal)


def _ray_to(point, port, normal):
    """The unit in-air direction from the centre whose traced ray passes through `point`:
    brentq on the in-air angle in the plane of the normal and the point; None if none does."""
    depth = point @ normal
    lateral = point - depth * normal
    rho = np.linalg.norm(lateral)
    if rho < 1e-12:  # on the normal, up to rounding
        return normal
    across = lateral / rho

    def miss(theta):
        p2, d3 = _trace(math.cos(theta) * normal + math.sin(theta) * across, port, normal)
        return (p2 + d3 * (depth - p2 @ normal) / (d3 @ normal)) @ across - rho

    # The largest in-air angle that passes both surfaces (beyond it, total reflection).
    n_min = min(port["n_air"], port["n_glass"], port["n_medium"])
    edge = math.asin(n_min / port["n_air"]) - 1e-9
    if miss(edge) < 0:
        return None
    theta = brentq(miss, 0.0, edge, xtol=1e-15, rtol=4 * np.finfo(float).eps, maxiter=500)
    return math.cos(theta) * normal + math.sin(theta) * across


# --- the model ------------------------------------------------------------------------------

_ray = jax.jit(lambda port, point: port.ray(point))  # one compilation for every port
_rays = jax.jit(lambda port, points: jax.vmap(port.ray)(points))  # (n, 3) -> (n, 3)


def _port_values(port, normal):
    normal = _port_normal(normal)
    return [*port.values(), normal[0], normal[1]]


def _camera(lens, lens_values, port=PORT, normal=NORMALS["axis"]):
    """The jaxba camera `lens` behind the port."""
    model = jaxba.CAMERA_MODELS[f"{lens}+flat_port"]
    return model.from_parameters(jnp.asarray([*lens_values, *_port_values(port, normal)]))


@jax.jit
def _projected(camera, points, measured):
    """`camera`'s image points of `points` (n, 3), corrected at `measured` (n, 2): one
    compilation per camera model (op by op: ~90 small programs)."""
    return jax.vmap(lambda p, m: camera.image_point(p, m, jnp.asarray(0.0)))(points, measured)


def _image_points(camera, points, measured):
    return np.asarray(_projected(camera, jnp.asarray(points), jnp.asarray(measured)))


def _grid(half_width, half_height, n=(9, 7)):
    """Image points over a format, corners and edges included: (n_x n_y, 2)."""
    x, y = np.meshgrid(np.linspace(-half_width, half_width, n[0]),
                       np.linspace(-half_height, half_height, n[1]))
    return np.c_[x.ravel(), y.ravel()]


def _depths(count):
    """Object depths along the normal, 0.3 to 6 object units (metres), cycled."""
    return np.resize([0.3, 0.8, 1.5, 3.0, 6.0], count)


@pytest.mark.parametrize("normal", list(NORMALS))
def test_smac_behind_the_port_projects_traced_rays_over_the_sensor(normal):
    """Image points over the sensor -> SMAC's ideal rays (NumPy corrections at the measured
    point) -> traced into the water -> points at several depths -> projected back by jaxba."""
    unit_normal = _port_normal(NORMALS[normal])
    measured = _grid(SENSOR_MM[0] / 2, SENSOR_MM[1] / 2)
    reduced = measured - [SMAC["xp"], SMAC["yp"]]
    ideal = reduced - np.stack(smac_correction(reduced[:, 0], reduced[:, 1], SMAC), axis=-1)
    directions = np.c_[ideal, np.full(len(ideal), -SMAC["c"])]
    points = np.array([_point_at_depth(d, PORT, unit_normal, z)
                       for d, z in zip(directions, _depths(len(directions)))])
    camera = _camera("smac", list(SMAC.values()), normal=NORMALS[normal])
    np.testing.assert_allclose(_image_points(camera, points, measured), measured, rtol=0,
                               atol=IMAGE_ATOL)


@pytest.mark.parametrize("normal", list(NORMALS))
def test_opencv_behind_the_port_projects_traced_rays_over_the_sensor(normal):
    """The same with a pixel model: (col, row) -> K⁻¹ (col, row, 1) in OpenCV's frame."""
    unit_normal = _port_normal(NORMALS[normal])
    fx, fy, cx, cy, skew = 500.0, 505.0, 499.5, 399.5, 0.3
    pixels = _grid(499.5, 399.5) + [cx, cy]
    k_inverse = np.linalg.inv([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    directions = (np.c_[pixels, np.ones(len(pixels))] @ k_inverse.T) @ CV_FROM_CAMERA
    points = np.array([_point_at_depth(d, PORT, unit_normal, z)
                       for d, z in zip(directions, _depths(len(directions)))])
    camera = _camera("opencv", [fx, fy, cx, cy, skew, 0.0, 0.0, 0.0, 0.0, 0.0],
                     normal=NORMALS[normal])
    np.testing.assert_allclose(_image_points(camera, points, np.zeros_like(pixels)), pixels,
                               rtol=0, atol=IMAGE_ATOL)


@pytest.mark.parametrize("normal", list(NORMALS))
def test_ray_to_a_point_matches_brentq(normal):
    """Random points (also on the normal, ρ = 0), and indices with the medium the thinnest."""
    rng = np.random.default_rng(40)
    unit_normal = _port_normal(NORMALS[normal])
    points = np.c_[rng.uniform(-3.0, 3.0, (40, 2)), -rng.uniform(0.2, 4.0, 40)]
    points[0] = 2.0 * unit_normal
    for port in (PORT, {**PORT, "n_air": 1.4, "n_medium": 1.0}):
        port_model = jaxba.FlatPort(*_port_values(port, NORMALS[normal]))
        rays = np.asarray(_rays(port_model, jnp.asarray(points)))
        for point, got in zip(points, rays):
            expected = _ray_to(point, port, unit_normal)
            assert got @ unit_normal == pytest.approx(point @ unit_normal, rel=1e-14)
            assert np.linalg.norm(np.cross(_unit(got), expected)) < RAY_ATOL


def test_invalid_geometry_is_nan():
    port = jaxba.FlatPort(*_port_values(PORT, TILTED))
    good = jnp.array([0.2, -0.1, -2.0])
    assert np.all(np.isfinite(np.asarray(_ray(port, good))))
    inside = jnp.array([0.0, 0.0, -(PORT["distance"] + PORT["thickness"] / 2)])  # in the glass
    behind = jnp.array([0.1, 0.1, 1.0])  # behind the camera
    for point in (inside, behind):
        assert np.all(np.isnan(np.asarray(_ray(port, point))))
    for name, bad in (("n_air", 0.0), ("n_glass", -1.5), ("n_medium", 0.0), ("thickness", -0.001),
                      ("distance", -0.01)):
        values = {**PORT, name: bad}
        invalid = jaxba.FlatPort(*_port_values(values, TILTED))
        assert np.all(np.isnan(np.asarray(_ray(invalid, good)))), name
    across = jaxba.FlatPort(*PORT.values(), 0.8, 0.7)  # normal_x² + normal_y² > 1
    assert np.all(np.isnan(np.asarray(_ray(across, good))))


def test_a_point_no_ray_reaches_is_nan():
    """No air between centre and glass: air rays at 90° reach the water at the critical angle,
    so points farther out than that are unreachable, also for the NumPy tracer."""
    port = {**PORT, "distance": 0.0}
    normal = np.array([0.0, 0.0, -1.0])
    model = jaxba.FlatPort(*_port_values(port, normal))
    reachable, unreachable = np.array([1.0, 0.0, -1.0]), np.array([3.0, 0.0, -1.0])
    assert _ray_to(unreachable, port, normal) is None
    assert np.all(np.isnan(np.asarray(_ray(model, jnp.asarray(unreachable)))))
    expected = _ray_to(reachable, port, normal)
    got = np.asarray(_ray(model, jnp.asarray(reachable)))
    assert np.linalg.norm(np.cross(_unit(got), expected)) < RAY_ATOL


# --- derivatives ----------------------------------------------------------------------------

IOP = np.array([*SMAC.values(), *_port_values(PORT, TILTED)])
EOP = np.array([0.3, -0.2, 2.4, 0.05, -0.08, 0.3])
POINT = np.array([0.9, 0.6, 0.1])
MEASURED = np.array([3.1, 2.2])
SIGMA = np.array([0.002, 0.002])


def _residual(iop, eop, point):
    return advanced.collinearity_residual("smac+flat_port", iop, eop, point, jnp.asarray(MEASURED),
                                       jnp.asarray(SIGMA), jaxba.NoRefraction())


def test_collinearity_jacobian_matches_fd():
    """d residual / d (camera and port parameters, pose, point), all at once: forward mode
    against central differences, and reverse mode (what the solvers use) against forward."""
    sizes = np.cumsum([IOP.size, EOP.size])

    @jax.jit
    def f(x):
        return _residual(*jnp.split(x, sizes))

    x = np.concatenate([IOP, EOP, POINT])
    forward = np.asarray(jax.jit(jax.jacfwd(f))(x))
    exact = central_difference(f, x, FD_STEP * np.maximum(1.0, np.abs(x)))
    np.testing.assert_allclose(forward, exact, rtol=FD_RTOL, atol=FD_ATOL)
    reverse = np.asarray(jax.jit(jax.jacrev(f))(x))
    np.testing.assert_allclose(reverse, forward, rtol=JACREV_RTOL,
                               atol=JACREV_RTOL * np.abs(forward).max())
    port = slice(len(SMAC), IOP.size)
    assert np.all(np.abs(forward[:, port]).max(axis=0) > 1e-6)  # every port parameter acts


def test_on_axis_point_has_finite_derivatives():
    """ρ = 0 (the point on the port normal): the ray's derivatives stay finite."""
    port = jaxba.FlatPort(*_port_values(PORT, TILTED))
    on_axis = 2.0 * _port_normal(TILTED)
    by_point, by_port = jax.jit(jax.jacrev(
        lambda p, v: jaxba.FlatPort.from_parameters(v).ray(p), argnums=(0, 1)))(
            jnp.asarray(on_axis), port.parameters())
    assert np.all(np.isfinite(np.asarray(by_point))) and np.all(np.isfinite(np.asarray(by_port)))


# --- a block simulated by the tracer --------------------------------------------------------

BLOCK_CAMERA = {**{k: SMAC[k] for k in ("xp", "yp", "c")}, "K1": -3.0e-4}
BLOCK_PORT = {**PORT, "normal": (0.03, -0.02)}  # normal_x, normal_y of the true port
BLOCK_FREE = ("xp", "yp", "c", "K1")
PORT_FREE = ("distance",)  # n_medium weighted: with c and K1 free it is nearly inseparable
NOISE_MM = 0.0015  # σ of the simulated image points, also the project's image_sigma


def _observe(points, station, m, rng):
    """Image points (mm) of `points` (n, 3) seen from `station` with rotation `m`: the traced
    ray to each point, its SMAC measured point (NumPy), noise; those on the sensor."""
    normal = _port_normal([*BLOCK_PORT["normal"], -1.0])
    iop = {**dict.fromkeys(SMAC, 0.0), **BLOCK_CAMERA}
    rays = np.array([_ray_to(m @ (p - station), PORT, normal) for p in points])
    ideal = -iop["c"] * rays[:, :2] / rays[:, 2:]
    xy = solve_measured(ideal, iop) + [iop["xp"], iop["yp"]] + rng.normal(0, NOISE_MM, ideal.shape)
    inside = np.all(np.abs(xy) < np.array(SENSOR_MM) / 2, axis=1)
    return np.flatnonzero(inside), xy[inside]


def _numbers(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _write_block(folder, rng):
    """A small block under water: 8 rolled, convergent images of 40 points in a 2.4 m × 2.4 m ×
    0.9 m volume 2.5 m away; 6 points fixed (the datum). Returns the project file and the
    truth (points, stations with their M)."""
    points = np.c_[rng.uniform(-1.2, 1.2, (40, 2)), rng.uniform(-0.6, 0.3, 40)]
    stations, matrices = [], []
    for k in range(8):
        angle = 2 * math.pi * k / 8
        station = np.array([0.9 * math.cos(angle), 0.9 * math.sin(angle), 2.5])
        stations.append(station)
        matrices.append(look_at(station, rng.normal(0.0, 0.1, 3), math.pi / 2 * (k % 4)))
    image_rows, observation_rows = [], []
    for k, (station, m) in enumerate(zip(stations, matrices)):
        approx = station + rng.normal(0, 0.02, 3)
        angles = np.degrees(opk_from_rotation(m)) + rng.normal(0, 0.5, 3)
        image_rows.append(f"img{k} C1 {_numbers([*approx, *angles])}")
        seen, xy = _observe(points, station, m, rng)
        observation_rows += [f"img{k} p{i} {_numbers(row)}" for i, row in zip(seen, xy)]
    fixed = set(range(6))
    point_rows = [f"p{i} {_numbers(p)} 0 0 0" if i in fixed
                  else f"p{i} {_numbers(p + rng.normal(0, 0.02, 3))} - - -"
                  for i, p in enumerate(points)]
    files = {
        "block.toml": f"""[project]\nimage_units = "mm"\n[files]\ncameras = "cameras.toml"
images = "images.txt"\nimage_points = "image_points.txt"\npoints = "points.txt"
[adjustment]\nimage_sigma = {NOISE_MM}\n""",
        "cameras.toml": f"""[C1]\nmodel = "smac"\nxp = 0.0\nyp = 0.0\nc = 8.4\nK1 = 0.0
free = {list(BLOCK_FREE)}\n[C1.refraction]\nmodel = "flat_port"\ndistance = 0.06
thickness = {PORT["thickness"]}\nn_glass = {PORT["n_glass"]}\nn_medium = {PORT["n_medium"]}
normal = [{BLOCK_PORT["normal"][0]}, {BLOCK_PORT["normal"][1]}, -1.0]
free = {list(PORT_FREE)}\n[C1.refraction.sigma]\nnormal = 0.01\nn_medium = 0.003\n""",
        "images.txt": "\n".join(image_rows) + "\n",
        "image_points.txt": "\n".join(observation_rows) + "\n",
        "points.txt": "\n".join(point_rows) + "\n",
    }
    for name, text in files.items():
        (folder / name).write_text(text)
    return folder / "block.toml", points


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """The simulated block's project file and true points (simulated once)."""
    return _write_block(tmp_path_factory.mktemp("block"), np.random.default_rng(41))


@pytest.fixture
def block_copy(block, tmp_path):
    """A copy of the block's project, to edit."""
    shutil.copytree(block[0].parent, tmp_path / "block")
    return tmp_path / "block" / block[0].name


def test_block_simulated_by_the_tracer_is_recovered(block):
    project_file, points = block
    project = jaxba.build_project(jaxba.read_project(project_file))
    model, row = project.camera_rows["C1"]
    assert model == "smac+flat_port"
    result = jaxba.adjust_project(project)
    assert result.converged, result.message
    assert SIGMA0_RANGE[0] < result.sigma0 < SIGMA0_RANGE[1]
    names = jaxba.CAMERA_MODELS[model].parameter_names
    values = dict(zip(names, np.asarray(result.parameters.cameras[model])[row]))
    stds = dict(zip(names, np.asarray(result.precision.std.cameras[model])[row]))
    unit = _port_normal([*BLOCK_PORT["normal"], -1.0])
    truth = {**BLOCK_CAMERA, **PORT, "normal_x": unit[0], "normal_y": unit[1]}
    for name in (*BLOCK_FREE, *PORT_FREE, "n_medium", "normal_x", "normal_y"):
        assert stds[name] > 0, name
        assert abs(values[name] - truth[name]) < TRUTH_SIGMAS * stds[name], (
            name, values[name], truth[name], stds[name])
    for name in ("thickness", "n_air", "n_glass"):  # fixed
        assert stds[name] == 0 and values[name] == truth[name]
    adjusted = np.asarray(result.parameters.points)
    point_stds = np.asarray(result.precision.std.points)
    order = [int(pid[1:]) for pid in project.point_ids]
    free = point_stds > 0
    assert np.all(np.abs(adjusted - points[order])[free] < TRUTH_SIGMAS * point_stds[free])


@pytest.mark.parametrize("edit, message", [
    (("n_medium = 1.337", "n_medium = 0.0"), r"\[C1.refraction\] n_medium: expected a number > 0"),
    (("n_glass = 1.49", "n_glass = -1.49"), r"\[C1.refraction\] n_glass: expected a number > 0"),
    (("thickness = 0.012", "thickness = -0.012"),
     r"\[C1.refraction\] thickness: expected a number ≥ 0"),
    (("distance = 0.06", ""), r"\[C1.refraction\] distance: missing"),
    (("-1.0]", "0.0]"), r"\[C1.refraction\] normal: .* across the optical axis"),
    (('model = "flat_port"', 'model = "dome_port"'),
     r"\[C1.refraction\] model: expected one of 'flat_port', got 'dome_port'"),
    (("free = ['distance']", "free = ['c']"),
     r"\[C1.refraction\] free: unknown parameter 'c'; allowed: distance, thickness"),
    (("free = ['distance']", "free = ['n_medium']"),
     r"\[C1.refraction.sigma\] n_medium: 'n_medium' is also in free"),
    (('model = "smac"', 'model = "smac+flat_port"'),
     r"\[C1\] model: 'smac\+flat_port': give the camera model alone"),
])
def test_bad_port_tables_are_refused_by_key(block_copy, edit, message):
    project_file = block_copy
    cameras = project_file.parent / "cameras.toml"
    text = cameras.read_text()
    assert edit[0] in text
    cameras.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(jaxba.ProjectError, match=rf"cameras.toml: {message}"):
        jaxba.read_project(project_file)


def test_normal_is_read_in_either_sense_and_any_length(block_copy):
    project_file = block_copy
    cameras = project_file.parent / "cameras.toml"
    text = cameras.read_text()
    normal = f'normal = [{BLOCK_PORT["normal"][0]}, {BLOCK_PORT["normal"][1]}, -1.0]'
    values = []
    for given in (normal, "normal = [-0.09, 0.06, 3.0]", ""):  # the same normal, the default
        cameras.write_text(text.replace(normal, given))
        camera = jaxba.read_project(project_file).cameras["C1"]
        values.append((camera.values["normal_x"], camera.values["normal_y"]))
    unit = _port_normal([*BLOCK_PORT["normal"], -1.0])
    np.testing.assert_allclose(values[:2], [unit[:2], unit[:2]], rtol=1e-15)
    assert values[2] == (0.0, 0.0)


def test_a_point_inside_the_housing_stops_the_adjustment_by_name(block):
    """A point approximated 2 cm in front of a camera (inside its port) has NaN residuals:
    the adjustment refuses to start and names its observations."""
    project = jaxba.build_project(jaxba.read_project(block[0]))
    problem = project.problem
    image = np.asarray(problem.initial.images)[0]
    m = np.asarray(jaxba.opk_to_matrix(jnp.asarray(image[3:])))
    point = project.point_ids.index("p10")
    inside = problem.initial.points.at[point].set(jnp.asarray(image[:3] - 0.02 * m[2]))
    problem = eqx.tree_at(lambda p: p.initial.points, problem, inside)
    project = dataclasses.replace(project, problem=problem)
    with pytest.raises(jaxba.DatumError, match=r"not finite at the approximations of .*p10"):
        jaxba.adjust_project(project)
