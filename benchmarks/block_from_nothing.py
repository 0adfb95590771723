"""A close-range block from nothing: deferred weak points, then the block adjusted again.

    python benchmarks/block_from_nothing.py [--images 60] [--points 26000] [--seed 0]

`jaxba.write_close_range_project` writes the block twice, with its approximations and without
any (every EOP `-`, the points table empty): far 2-ray points under 2°, 30 px of distortion
at the corner with the camera's 0, two sparse images. From nothing: `complete_project`
(deferring the points it cannot intersect), `adjust_project`, then `adjust_deferred`; from the
approximations: `adjust_project`. Prints the counts (deferred, added, left out, suspects), the
iterations and σ̂0 of both and their relative difference, and the CPU seconds of each phase
(the process's, all threads: a loaded machine does not inflate them; compilation included,
the persistent cache as it is). JSON on the last line.
"""

import argparse
import json
import os
import tempfile
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jaxba  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=60)
    parser.add_argument("--points", type=int, default=26_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    size = dict(seed=args.seed, n_images=args.images, n_points=args.points)
    cpu: dict[str, float] = {}

    def timed(name, function, *arguments):
        start = time.process_time()
        value = function(*arguments)
        cpu[name] = round(time.process_time() - start, 2)
        return value

    with tempfile.TemporaryDirectory() as folder:
        truth = jaxba.write_close_range_project(f"{folder}/truth", **size)
        jaxba.write_close_range_project(f"{folder}/bare", approximations=False, **size)
        spec = jaxba.read_project(f"{folder}/bare/{truth.project_file.name}")
        completed, completion = timed("complete_project", jaxba.complete_project, spec)
        project = jaxba.build_project(completed)
        first = timed("adjust without the deferred", jaxba.adjust_project, project)
        _, second, deferral = timed("adjust_deferred", jaxba.adjust_deferred, completion,
                                    project, first)
        reference = jaxba.build_project(jaxba.read_project(truth.project_file))
        from_truth = timed("adjust from the approximations", jaxba.adjust_project, reference)
    summary = {
        "images": len(spec.images), "points": len(spec.points),
        "image_points": len(spec.image_points), "deferred": len(completion.deferred),
        "added": len(deferral.added), "left_out": len(deferral.left_out),
        "suspects": len(completion.suspects),
        "iterations_from_nothing": [len(first.iterations), len(second.iterations)],
        "iterations_from_approximations": len(from_truth.iterations),
        "sigma0_from_nothing": second.sigma0, "sigma0_from_approximations": from_truth.sigma0,
        "sigma0_relative_difference": second.sigma0 / from_truth.sigma0 - 1,
        "cpu_seconds": cpu,
    }
    for key, value in summary.items():
        print(f"{key:32s} {value}")
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
