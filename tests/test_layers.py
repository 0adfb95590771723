"""The package's layers: one folder per layer, imports pointing down only.

models < problem < solvers < statistics < project (the project model: the specs of a
project's files, built into a problem with the IDs of its rows) < adjust (orchestration:
completing, adjusting) < io (project files, importers, exporters) < report (the reports of a
`Project`) < cli (the commands, and batches of project files end to end). A module imports
from its own folder or from a lower rank: the project model never imports adjust nor io, io
never imports report nor cli, report never imports cli. Only cli may also use the
public face `jaxba` (which re-exports every room: through it, io could reach report). The
closed-form approximations (`_approximations`) sit beside the statistics, under the block
initialisation that uses them. A handful of shared
helpers (`_lazy`, `_custom_types`, `_float64`, `_timing`, `_gc`, `_memory`, `_jax_setup`,
`_files`, `_dask`, `_programs`) sit below everything. Every import counts, the ones inside
functions included, but the package's version (`from jaxba import __version__`: metadata,
not the public face).
"""

import ast
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "jaxba"
BASE = {"_lazy", "_custom_types", "_float64", "_timing", "_gc", "_memory", "_jax_setup", "_files",
        "_dask", "_programs"}
LAYERS = {
    "_models": 1, "_problem": 2, "_solvers": 3, "_statistics": 4, "_approximations": 4,
    "_project": 5, "_adjust": 6, "_io": 7, "_report": 8, "_cli": 9,
}
PUBLIC_FACE = 10


def _modules() -> dict[str, pathlib.Path]:
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def _imports(module: str, path: pathlib.Path) -> set[str]:
    """Every jaxba module `module` imports, resolved to dotted names."""
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    targets = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets |= {alias.name for alias in node.names if alias.name.startswith("jaxba")}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            metadata = name == "jaxba" and {a.name for a in node.names} == {"__version__"}
            if name.startswith("jaxba") and not metadata:
                targets.add(name)
    return targets


def _layer(module: str) -> tuple[str, int]:
    """(folder, rank) of a module: its folder under jaxba, or the base helpers (rank 0)."""
    parts = module.split(".")
    if len(parts) == 1 or parts[1] in {"__main__", "advanced"}:
        return "jaxba", PUBLIC_FACE  # the public face (and jaxba.advanced) re-exports all
    top = parts[1]
    if top in BASE:
        return top, 0
    if top not in LAYERS:
        raise AssertionError(f"{module} is in no layer folder ({sorted(LAYERS)}) nor a base helper")
    return top, LAYERS[top]


MODULES = _modules()


@pytest.mark.parametrize("module", sorted(MODULES))
def test_module_lives_in_a_layer(module):
    _layer(module)


def _upward(module: str, path: pathlib.Path) -> list[str]:
    """The imports of `module` (at `path`) that break the rule of the module docstring."""
    folder, rank = _layer(module)
    upward = []
    for target in sorted(_imports(module, path)):
        target_folder, target_rank = _layer(target)
        public_face = target == "jaxba" and folder == "_cli"  # the CLI uses the public API
        if target_rank > rank and not public_face:
            upward.append(f"{target} ({target_folder})")
    return upward


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_point_down(module):
    upward = _upward(module, MODULES[module])
    assert not upward, f"{module} ({_layer(module)[0]}) imports upward: {', '.join(upward)}"


@pytest.mark.parametrize("module, source", [
    ("jaxba._models._cameras.bad", "from ..._adjust._adjust import adjust\n"),
    ("jaxba._io._project.bad", "def f():\n    from ..._report import write_reports\n"),
    ("jaxba._io._project.bad", "import jaxba\n"),
    ("jaxba._report.bad", "from .._cli._batch_run import run_batch\n"),
    ("jaxba._io.bad", "from .. import _report\n"),
    ("jaxba._project.bad", "from .._adjust._complete import complete_project\n"),
    ("jaxba._project._build", "from .._io._project import read_project\n"),
    ("jaxba._statistics.bad", "from .._project._build import Project\n"),
])
def test_the_check_sees_an_upward_import(tmp_path, module, source):
    bad = tmp_path / "bad.py"
    bad.write_text(source)
    assert _upward(module, bad)


def test_the_check_lets_imports_point_down(tmp_path):
    good = tmp_path / "good.py"
    good.write_text("from ..._files import replace_files\nfrom ..._adjust import _pipeline\n"
                    "from ..._project._build import Project\nfrom ... import __version__\n")
    assert _upward("jaxba._io._project.good", good) == []
    adjust = tmp_path / "adjust.py"
    adjust.write_text("from .._project._spec import ProjectSpec\nfrom ._initialise import x\n")
    assert _upward("jaxba._adjust.good", adjust) == []
