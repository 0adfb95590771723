"""The README's main job in seconds: `jaxba adjust` against the import of jaxba, fresh processes.

    python benchmarks/main_job.py [--repeats 3] [--json OUT.json]

Each command runs in a new process with OPENBLAS_NUM_THREADS=1 and its own HOME, so that
"cold" starts with an empty persistent compilation cache (~/.cache/jaxba/jax) and "warm"
reuses the cache the cold run filled. Python writes and reads its bytecode caches as for an
installed package (PYTHONDONTWRITEBYTECODE is dropped; a first import writes them).
Measured, as the median wall time of `--repeats` runs:

- `import jax`, then `import jaxba` (the package's names are loaded lazily, so this loads no
  jax), `import jaxba; jaxba.adjust` (jax and the adjustment code: the floor of any
  adjustment) and every public name loaded (what `import jaxba` did before the names were
  lazy, the reference the targets were set against), `import jax` and every public name
  alternated;
- `jaxba adjust configs/lab/lab.toml`, cold (first run, empty cache) and warm;
- `jaxba adjust configs/zhang/zhang.toml`, warm;
- an input error (a project naming an unknown image), reported before jax is loaded.

Prints a Markdown table with each wall time as a ratio to both loaded imports.
"""

import argparse
import json
import os
import pathlib
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

from _processes import process_environment

ROOT = pathlib.Path(__file__).resolve().parents[1]
JAXBA = [sys.executable, "-m", "jaxba"]
EVERY_NAME = "import jaxba; [getattr(jaxba, name) for name in jaxba.__all__]"


def _wall(command: list[str], home: pathlib.Path, *, expect: int = 0) -> float:
    """Seconds of one run of `command` in a fresh process with HOME=`home`."""
    env = process_environment(HOME=str(home))
    start = time.perf_counter()
    done = subprocess.run(command, env=env, capture_output=True, text=True, cwd=ROOT)
    seconds = time.perf_counter() - start
    if done.returncode != expect:
        raise RuntimeError(f"{' '.join(command)} exited {done.returncode}:\n{done.stderr}")
    return seconds


def _median(command, home, repeats, **kwargs) -> float:
    return statistics.median(_wall(command, home, **kwargs) for _ in range(repeats))


def _bad_project(folder: pathlib.Path) -> pathlib.Path:
    """A copy of the lab whose image points name an image that does not exist."""
    shutil.copytree(ROOT / "configs" / "lab", folder)
    table = folder / "image_coordinates.txt"
    lines = table.read_text().splitlines()
    first = next(k for k, line in enumerate(lines) if line.strip() and not line.startswith("#"))
    lines[first] = "no_such_image " + lines[first].split(maxsplit=1)[1]
    table.write_text("\n".join(lines) + "\n")
    return folder / "lab.toml"


def measure(repeats: int) -> dict[str, float]:
    """Median wall seconds of every command (see the module docstring)."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        out = str(tmp / "out")
        lab = ["adjust", "configs/lab/lab.toml", "--out", out]
        zhang = ["adjust", "configs/zhang/zhang.toml", "--out", out]
        bad = ["adjust", str(_bad_project(tmp / "bad")), "--out", out]
        every_name = [sys.executable, "-c", EVERY_NAME]
        _wall(every_name, tmp)  # writes the bytecode caches an installed package has
        jax_alone, every = [], []
        for _ in range(repeats):
            jax_alone.append(_wall([sys.executable, "-c", "import jax"], tmp))
            every.append(_wall(every_name, tmp))
        results = {
            "import jax": statistics.median(jax_alone),
            "import jaxba": _median([sys.executable, "-c", "import jaxba"], tmp, repeats),
            "import jaxba; jaxba.adjust": _median(
                [sys.executable, "-c", "import jaxba; jaxba.adjust"], tmp, repeats),
            "import jaxba, every public name": statistics.median(every),
        }
        cold = []
        for k in range(repeats):
            home = tmp / f"cold{k}"
            home.mkdir()
            cold.append(_wall(JAXBA + lab, home))
        results["lab, cold cache"] = statistics.median(cold)
        results["lab, warm cache"] = _median(JAXBA + lab, tmp / "cold0", repeats)
        _wall(JAXBA + zhang, tmp / "cold0")  # fills the cache with Zhang's programs
        results["zhang, warm cache"] = _median(JAXBA + zhang, tmp / "cold0", repeats)
        results["input error"] = _median(JAXBA + bad, tmp / "cold0", repeats, expect=2)
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=pathlib.Path, default=None)
    args = parser.parse_args()
    results = measure(args.repeats)
    adjust_only = results["import jaxba; jaxba.adjust"]
    every_name = results["import jaxba, every public name"]
    print(f"load average {os.getloadavg()[0]:.2f}, OPENBLAS_NUM_THREADS=1,"
          f" median of {args.repeats}\n")
    print("| command | wall s | / import with every name | / import with jaxba.adjust |")
    print("|---|---|---|---|")
    for name, seconds in results.items():
        print(f"| {name} | {seconds:.2f} | {seconds / every_name:.2f} |"
              f" {seconds / adjust_only:.2f} |")
    print(f"\nevery public name beyond import jax: {every_name - results['import jax']:.2f} s"
          " (target: at most 0.5)")
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
