"""`jaxba compare A/results.json B/results.json [--camera C1[:C2]] [--distance D]
[--fit rotation|none] --out DIR`: the projection difference of two calibrations of one camera
(`jaxba.compare`), written as compare_CAMERA.csv (u v du dv norm chi2), compare_CAMERA.json
(the χ² test) and compare_CAMERA.png (a heat map of |Δ|), the test printed."""

import argparse
import json
import math
import pathlib

from ._common import EXIT_OK, UsageError, common_options, say

ALPHA = 0.05  # the level of the verdict printed


def add_compare(subparsers) -> None:
    """Register `jaxba compare`."""
    parser = subparsers.add_parser(
        "compare",
        help="compare two calibrations of one camera: projection difference and χ² test",
        description=(
            "The projection difference of two calibrations of one camera over its sensor,"
            " after the rotation that best aligns them (weighted by both covariances) or none,"
            " and the χ² test of the difference against both covariances. Writes"
            " compare_CAMERA.csv, compare_CAMERA.json and compare_CAMERA.png into DIR."
        ),
        parents=[common_options()],
    )
    parser.add_argument("a", type=pathlib.Path, metavar="A/results.json")
    parser.add_argument("b", type=pathlib.Path, metavar="B/results.json")
    parser.add_argument("--camera", default=None, metavar="C1[:C2]",
                        help="the camera's ID in both files, or C1 in A and C2 in B"
                             " (default: the only camera of each)")
    parser.add_argument("--distance", type=float, default=math.inf, metavar="D",
                        help="object units along A's rays (default: infinity)")
    parser.add_argument("--fit", choices=("rotation", "none"), default="rotation",
                        help="align the cameras by the best rotation (default) or not")
    parser.add_argument("--out", type=pathlib.Path, required=True, metavar="DIR")
    parser.set_defaults(run=_compare)


def _file_part(camera_id: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in camera_id)


def _csv(comparison) -> str:
    rows = ["u,v,du,dv,norm,chi2"]
    for (u, v), (du, dv), norm, chi2 in zip(comparison.pixels, comparison.difference,
                                            comparison.norm, comparison.chi2_pixels):
        rows.append(",".join(f"{x:.10g}" for x in (u, v, du, dv, norm, chi2)))
    return "\n".join(rows) + "\n"


def _summary(comparison, a, b) -> dict:
    return {
        "a": a.name, "b": b.name, "fit": comparison.fit,
        "distance": None if math.isinf(comparison.distance) else comparison.distance,
        "rotation_degrees": [math.degrees(r) for r in comparison.rotation],
        "chi2": comparison.chi2, "dof": comparison.dof, "rank": comparison.rank,
        "p_value": comparison.p_value, "alpha": ALPHA,
        "rejected": bool(comparison.rejected(ALPHA)),
        "rms_difference_px": float(math.sqrt((comparison.norm**2).mean())),
        "max_difference_px": float(comparison.norm.max()),
    }


def _compare(args: argparse.Namespace) -> int:
    from jaxba._jax_setup import setup_jax

    setup_jax()
    from jaxba._files import check_folder, check_targets, replace_files
    from jaxba._io._calibration import camera_pair, read_calibration
    from jaxba._report import png_bytes
    from jaxba._report._plots._uncertainty import plot_sensor_map
    from jaxba._statistics._compare import compare_calibrations

    try:
        first, second = camera_pair(args.camera)
        a, b = read_calibration(args.a, first), read_calibration(args.b, second)
        check_folder(args.out)
        stem = args.out / f"compare_{_file_part(a.camera)}"
        files = [stem.with_suffix(s) for s in (".csv", ".json", ".png")]
        check_targets(files, [args.a, args.b], "the comparison")
        comparison = compare_calibrations(a, b, distance=args.distance, fit=args.fit)
    except ValueError as error:
        raise UsageError(str(error)) from None
    summary = _summary(comparison, a, b)
    where = "at infinity" if math.isinf(args.distance) else f"at distance {args.distance:g}"
    figure = plot_sensor_map(
        comparison.pixels, comparison.norm, a.sensor,
        title=f"{a.camera}: |Δ| of {pathlib.Path(args.b).parent.name or args.b} against"
              f" {pathlib.Path(args.a).parent.name or args.a} {where}, fit {args.fit}",
        label="|Δ| (px)")
    args.out.mkdir(parents=True, exist_ok=True)
    replace_files({files[0]: _csv(comparison), files[1]: json.dumps(summary, indent=2) + "\n",
                   files[2]: png_bytes(figure)})
    verdict = "different" if summary["rejected"] else "consistent"
    rotation = ", ".join(f"{r:.5f}" for r in summary["rotation_degrees"])
    say(f"{a.name} vs {b.name}: |Δ| RMS {summary['rms_difference_px']:.4g} px, max"
        f" {summary['max_difference_px']:.4g} px; fitted rotation ({rotation}) deg\n"
        f"χ² = {comparison.chi2:.4g} with {comparison.dof} degrees of freedom,"
        f" p = {comparison.p_value:.4g}: {verdict} at α = {ALPHA}\nwrote")
    for path in files:
        say(f"  {path}")
    return EXIT_OK
