"""The public names load only what every run needs: the heavy optional modules (plots,
statistics tables, Dask, pandas, console formatting) are imported where they are used."""

import gc
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


def test_import_jaxba_loads_neither_jax_nor_the_package_metadata():
    """`import jaxba` (the command line's start, its input checks) loads no jax and no
    `importlib.metadata` (~35 ms); `jaxba.__version__` reads the metadata when asked."""
    assert _loaded("import jaxba", ("jax", "importlib.metadata")) == []
    assert _loaded("import jaxba; jaxba.__version__", ("importlib.metadata",)) == [
        "importlib.metadata"]


def test_a_lazy_name_is_imported_with_the_collector_paused(tmp_path, monkeypatch):
    """A module behind a lazy name is imported with the cyclic collector paused (its passes
    walked jax's objects), and the collector is left as it was."""
    package = tmp_path / "lazy_package"
    package.mkdir()
    (package / "__init__.py").write_text(
        "from jaxba._lazy import lazy_exports\n"
        "__getattr__, __dir__, __all__ = lazy_exports(__name__, {'._part': ('collecting',)})\n")
    (package / "_part.py").write_text("import gc\ncollecting = gc.isenabled()\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import lazy_package

    assert gc.isenabled()
    assert lazy_package.collecting is False
    assert gc.isenabled()
