"""Parameter names of the camera models, by the name a cameras.toml gives (no jax here, so
that project files are checked before jax is loaded). Each model class takes its
`parameter_names` from this table."""

RADIAL_SMAC = ("K0", "K1", "K2", "K3")
DECENTERING_SMAC = ("P1", "P2", "P3")
AFFINE = ("A1", "A2")

CAMERA_PARAMETER_NAMES: dict[str, tuple[str, ...]] = {
    "smac": ("xp", "yp", "c", *RADIAL_SMAC, *DECENTERING_SMAC, *AFFINE),
    "opencv": ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3"),
    "opencv_full": ("fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "k4", "k5",
                    "k6", "s1", "s2", "s3", "s4"),
    "photomodeler": ("xp", "yp", "c", "K1", "K2", "K3", "P1", "P2", "aspect", "skew"),
    "bal": ("f", "k1", "k2"),
    "fisheye": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
    "metrology": ("xh", "yh", "c", "A1", "A2", "A3", "B1", "B2", "C1", "C2"),
}

RAY_REFRACTION_PARAMETER_NAMES: dict[str, tuple[str, ...]] = {
    "flat_port": ("distance", "thickness", "n_air", "n_glass", "n_medium",
                  "normal_x", "normal_y"),
}
"""Parameter names of the ray refraction models a camera's `[ID.refraction]` table names."""

REFRACTION_SEPARATOR = "+"
"""A camera behind a ray refraction model is the model "<camera>+<refraction>" (e.g.
"smac+flat_port"): the camera's parameters, then the refraction's."""


def lens_model(model: str) -> str:
    """The camera model of a model name without its ray refraction ("smac+flat_port" ->
    "smac")."""
    lens, separator, refraction = model.rpartition(REFRACTION_SEPARATOR)
    return lens if separator and refraction in RAY_REFRACTION_PARAMETER_NAMES else model


PIXEL_MODELS = frozenset({"opencv", "opencv_full", "fisheye", "bal"})
"""The built-in models whose image points are pixels (`image_units = "pixel"`): they need no
pixel size (a mm model in a pixel project converts its image points with it)."""

CAMERA_CONSTANT_NAMES: dict[str, tuple[str, ...]] = {"metrology": ("r0",)}
"""Per model, its constants: values of the camera that are never unknowns (cameras.toml
keys, required for the model and refused for the others), e.g. the radius r0 (mm) where
the metrology model's balanced radial distortion crosses zero."""

PRINCIPAL_DISTANCES: dict[str, tuple[str, ...]] = {
    "smac": ("c",), "opencv": ("fx", "fy"), "opencv_full": ("fx", "fy"),
    "photomodeler": ("c",), "bal": ("f",), "fisheye": ("fx", "fy"), "metrology": ("c",),
}
"""Per model, the parameters that are a principal distance (focal length): > 0, or the
model divides by 0 or mirrors the image (`read_project` refuses others)."""

INSEPARABLE_PARAMETERS: dict[str, tuple[tuple[str, str, str], ...]] = {
    "smac": (("K0", "c", "K0 x̄ scales the image as c does"),),
}
"""Per model, pairs of parameters that the observations cannot separate (a datum defect
when both are free without a prior), with the reason: `check_datum` refuses them."""

DISTORTION_TERMS: dict[str, dict[str, tuple[str, ...]]] = {
    "smac": {"radial": RADIAL_SMAC, "decentering": DECENTERING_SMAC, "affine": AFFINE},
    "opencv": {"radial": ("k1", "k2", "k3"), "decentering": ("p1", "p2"), "affine": ("skew",)},
    "opencv_full": {"radial": ("k1", "k2", "k3", "k4", "k5", "k6"), "decentering": ("p1", "p2"),
                    "thin_prism": ("s1", "s2", "s3", "s4"), "affine": ("skew",)},
    "photomodeler": {"radial": ("K1", "K2", "K3"), "decentering": ("P1", "P2"),
                     "affine": ("aspect", "skew")},
    "bal": {"radial": ("k1", "k2")},
    "fisheye": {"radial": ("k1", "k2", "k3", "k4")},
    "metrology": {"radial": ("A1", "A2", "A3"), "decentering": ("B1", "B2"),
                  "affine": ("C1", "C2")},
}
"""Per model, its image-correction terms by kind: the parameters that vanish for an ideal
camera of the model (the rest: principal point and distance). `jaxba._statistics._distortion`
draws each kind alone by setting the others to 0."""
