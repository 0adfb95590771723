"""Project files -> BundleProblem: one image-point group per camera model, however many
cameras, so that the traced programs do not grow with the number of cameras."""

import jax
import numpy as np

import jaxba
from jaxba._problem._observations import ImagePoints
from jaxba._project._build import put_on_device


def _equations(jaxpr) -> int:
    """The number of equations of a jaxpr, those of its sub-jaxprs (vmap, jacrev, pjit)
    included."""
    count = 0
    for equation in jaxpr.eqns:
        count += 1
        for value in equation.params.values():
            for sub in value if isinstance(value, (list, tuple)) else (value,):
                inner = getattr(sub, "jaxpr", sub)
                if hasattr(inner, "eqns"):
                    count += _equations(inner)
    return count


def _block(tmp_path, n_cameras: int):
    folder = tmp_path / f"cameras{n_cameras}"
    truth = jaxba.write_synthetic_project(folder, seed=3, n_images=20, n_targets=30,
                                          n_cameras=n_cameras, n_distances=0)
    return jaxba.build_project(jaxba.read_project(truth.project_file))


def _program_size(project) -> int:
    """Equations of the residuals and of the per-row Jacobians of every group."""
    problem = project.problem

    def rows(params):
        return [group.row_jacobians(params, problem.refraction) for group in problem.groups]

    return (_equations(jax.make_jaxpr(problem.residuals)(problem.initial).jaxpr)
            + _equations(jax.make_jaxpr(rows)(problem.initial).jaxpr))


def test_twenty_cameras_trace_the_program_of_two(tmp_path):
    two, twenty = _block(tmp_path, 2), _block(tmp_path, 20)
    for project, n in ((two, 2), (twenty, 20)):
        image_groups = [g for g in project.problem.groups if isinstance(g, ImagePoints)]
        assert [g.name for g in image_groups] == ["image_points"]
        assert len(project.camera_rows) == n
        # Every row's camera is its image's camera, as a row of the model's block.
        group = image_groups[0]
        image_camera = [project.camera_rows[project.spec.images[i].camera][1]
                        for i in project.image_ids]
        np.testing.assert_array_equal(np.asarray(group.camera),
                                      np.asarray(image_camera)[np.asarray(group.image)])
    assert _program_size(twenty) == _program_size(two)


def test_parts_name_every_camera(tmp_path):
    project = _block(tmp_path, 3)
    group = next(g for g in project.problem.groups if isinstance(g, ImagePoints))
    names, index = group.parts({group.model: ("C1", "C2", "C3")})
    assert names == ("image_points:C1", "image_points:C2", "image_points:C3")
    cameras = np.array([project.spec.images[i].camera for i in project.image_ids])
    np.testing.assert_array_equal(np.asarray(names)[index],
                                  "image_points:" + cameras[np.asarray(group.image)])


def test_a_project_built_off_the_device_holds_the_same_arrays(tmp_path):
    """`on_device=False` (the batch's: padded and stacked in NumPy) leaves the problem's
    arrays NumPy arrays, equal to the default's device arrays; `put_on_device` transfers
    them, the structure unchanged."""
    truth = jaxba.write_synthetic_project(tmp_path / "p", seed=3, n_images=6, n_targets=20)
    spec = jaxba.read_project(truth.project_file)
    device, host = jaxba.build_project(spec), jaxba.build_project(spec, on_device=False)
    device_leaves, device_tree = jax.tree.flatten(device.problem)
    host_leaves, host_tree = jax.tree.flatten(host.problem)
    assert host_tree == device_tree
    arrays = [k for k, leaf in enumerate(device_leaves) if isinstance(leaf, jax.Array)]
    assert arrays and not any(isinstance(host_leaves[k], jax.Array) for k in arrays)
    for k in arrays:
        np.testing.assert_array_equal(host_leaves[k], device_leaves[k])
    moved = put_on_device(host)
    assert jax.tree.structure(moved.problem) == device_tree
    assert all(isinstance(jax.tree.leaves(moved.problem)[k], jax.Array) for k in arrays)
    assert moved.labels == device.labels
