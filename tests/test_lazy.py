"""The public names load only what every run needs: the heavy optional modules (plots,
statistics tables, Dask, pandas, console formatting) are imported where they are used."""

import subprocess
import sys

# Imported by their users only: each costs 0.1-0.8 s of a run that does not use it.
NOT_WITH_THE_NAMES = ("matplotlib", "scipy.stats", "scipy.linalg", "scipy.optimize",
                      "scipy.sparse", "scipy.special", "rich", "dask", "distributed", "pandas")


def _loaded(script: str, modules: tuple[str, ...]) -> list[str]:
    """The `modules` loaded by a fresh interpreter after running `script`."""
    check = f"; import sys; print(*[m for m in {modules!r} if m in sys.modules])"
    done = subprocess.run([sys.executable, "-c", script + check], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.split()


def test_every_public_name_loads_without_the_heavy_modules():
    script = "import jaxba; names = [getattr(jaxba, name) for name in jaxba.__all__]"
    assert _loaded(script, NOT_WITH_THE_NAMES) == []

