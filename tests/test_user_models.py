"""User camera models: `model = "package.module:ClassName"` in cameras.toml, entry points of the
group "jaxba.cameras", and the errors for a model that cannot be used."""

import contextlib
import importlib.metadata
import io
import json
import textwrap

import numpy as np
import pytest

import jaxba
from jaxba._cli._main import main
from jaxba._io._synthetic import write_synthetic_project

# The documented minimal example (docs/models.md), with a module name of its own per test:
# modules and resolved models are cached per process.
PINHOLE = textwrap.dedent('''
    import jax
    import jax.numpy as jnp

    import jaxba


    class Pinhole(jaxba.AbstractCamera):
        """x = xp - c U/W, y = yp - c V/W (mm): collinearity without distortion."""

        xp: jax.Array
        yp: jax.Array
        c: jax.Array
        parameter_names = ("xp", "yp", "c")
        image_units = "mm"

        def image_point(self, p_camera, measured, refraction_k):
            return jnp.stack([self.xp, self.yp]) - self.c * p_camera[:2] / p_camera[2]


    class NotACamera:
        parameter_names = ("xp", "yp", "c")


    class Misnamed(Pinhole):
        parameter_names = ("xp", "yp", "c", "k1")
''')
TRUTH = {"xp": 0.012, "yp": -0.008, "c": 8.52}
TRUTH_ATOL = 1e-7  # mm: noise-free image points (8 decimals), distances with σ = noise = 1e-8 m


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def _pinhole_project(tmp_path, monkeypatch, module: str, model: str):
    """A small noise-free block of a camera without distortion, its cameras.toml naming
    `model`; the Pinhole module written as `module`.py on sys.path."""
    (tmp_path / f"{module}.py").write_text(PINHOLE)
    monkeypatch.syspath_prepend(str(tmp_path))
    truth = write_synthetic_project(tmp_path / "block", n_images=6, n_targets=30, camera=TRUTH,
                                    noise_px=0.0, distance_sigma=1e-8, free=("xp", "yp", "c"))
    (tmp_path / "block" / "cameras.toml").write_text(
        f'[C1]\nmodel = "{model}"\nxp = 0.0\nyp = 0.0\nc = 8.5\nfree = ["xp", "yp", "c"]\n')
    return truth


def test_adjust_loads_a_user_model_from_a_module(tmp_path, monkeypatch):
    truth = _pinhole_project(tmp_path, monkeypatch, "user_pinhole_cli",
                             "user_pinhole_cli:Pinhole")
    code, out, err = _run("adjust", str(truth.project_file), "--out", str(tmp_path / "out"))
    assert code == 0, out + err
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    camera = results["cameras"]["C1"]
    assert sorted(camera) == sorted(TRUTH)
    for name, value in TRUTH.items():
        assert camera[name]["value"] == pytest.approx(value, abs=TRUTH_ATOL)
        assert camera[name]["status"] == "free"
    assert results["sigma0"] < 1e-4  # the image points' 8 decimals: σ̂0 ≈ 3e-9 mm / σ 9e-4 mm


def test_entry_point_lookup(tmp_path, monkeypatch):
    """A name that is not built in is looked up in the entry points of "jaxba.cameras"."""
    truth = _pinhole_project(tmp_path, monkeypatch, "user_pinhole_ep", "pinhole_ep")
    group = "jaxba.cameras"
    installed = [
        importlib.metadata.EntryPoint("pinhole_ep", "user_pinhole_ep:Pinhole", group),
        importlib.metadata.EntryPoint("other", "user_pinhole_ep:Pinhole", group),
    ]
    asked = []

    def entry_points(**selection):
        asked.append(selection)
        return [entry for entry in installed if entry.group == selection.get("group")]

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    project = jaxba.build_project(jaxba.read_project(truth.project_file))
    assert asked == [{"group": group}]
    model, _ = project.camera_rows["C1"]
    assert model == "pinhole_ep"
    assert jaxba.CAMERA_MODELS["pinhole_ep"].__name__ == "Pinhole"
    assert "pinhole_ep" not in list(jaxba.CAMERA_MODELS)  # found, not listed as built in
    result = jaxba.adjust_project(project)
    values = np.asarray(result.parameters.cameras[model])[0]
    np.testing.assert_allclose(values, list(TRUTH.values()), atol=TRUTH_ATOL)
    # A name that no entry point has: the error lists the installed ones.
    cameras = truth.project_file.parent / "cameras.toml"
    cameras.write_text(cameras.read_text().replace("pinhole_ep", "pinhole_typo"))
    with pytest.raises(jaxba.ProjectError,
                       match=r"cameras.toml: \[C1\] model: unknown camera model 'pinhole_typo'"
                             r".*entry points 'jaxba.cameras'\): other, pinhole_ep"):
        jaxba.read_project(truth.project_file)


@pytest.mark.parametrize("model, message", [
    ("user_missing_module:Pinhole", r"cannot import module 'user_missing_module'"),
    ("user_pinhole_errors:Nothing", r"module 'user_pinhole_errors' has no 'Nothing'"),
    ("user_pinhole_errors:NotACamera",
     r"<class 'user_pinhole_errors.NotACamera'> is not a subclass of jaxba.AbstractCamera"),
    ("user_pinhole_errors:Misnamed", r"Misnamed.from_parameters\(values of xp, yp, c, k1\)"
                                     r" fails .*parameter_names must match its fields"),
])
def test_a_model_that_cannot_be_used_is_refused_by_name(tmp_path, monkeypatch, model, message):
    truth = _pinhole_project(tmp_path, monkeypatch, "user_pinhole_errors", model)
    with pytest.raises(jaxba.ProjectError, match=rf"cameras.toml: \[C1\] model: camera model"
                                                 rf" '{model}': {message}"):
        jaxba.read_project(truth.project_file)


def test_table_keys_must_be_the_models_parameters(tmp_path, monkeypatch):
    model = "user_pinhole_keys:Pinhole"
    truth = _pinhole_project(tmp_path, monkeypatch, "user_pinhole_keys", model)
    cameras = truth.project_file.parent / "cameras.toml"
    cameras.write_text(cameras.read_text().replace("c = 8.5", "c = 8.5\nK1 = 0.0"))
    with pytest.raises(jaxba.ProjectError, match=r"\[C1\]: unknown key 'K1'; allowed keys: .*"
                                                 r"xp, yp, c"):
        jaxba.read_project(truth.project_file)
    cameras.write_text(cameras.read_text().replace('"c"]', '"c", "K1"]').replace("K1 = 0.0", ""))
    with pytest.raises(jaxba.ProjectError,
                       match=rf"free: unknown parameter 'K1' for model '{model}'; allowed:"
                             r" xp, yp, c"):
        jaxba.read_project(truth.project_file)
