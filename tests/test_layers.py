"""The package's layers: one folder per layer, imports pointing down only.

models < problem < solvers < statistics < adjust (orchestration) < io, report, cli (the
practical edges, which may also use the public face `jaxba`); the closed-form
approximations (`_approximations`) sit beside the statistics, under the block initialisation
that uses them. A handful of shared helpers (`_lazy`, `_custom_types`, `_float64`, `_timing`,
`_gc`, `_memory`, `_jax_setup`, `_files`, `_dask`, `_programs`) sit below everything. Every
import counts, the ones inside functions included.
"""

import ast
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "jaxba"
BASE = {"_lazy", "_custom_types", "_float64", "_timing", "_gc", "_memory", "_jax_setup", "_files",
        "_dask", "_programs"}
LAYERS = {
    "_models": 1, "_problem": 2, "_solvers": 3, "_statistics": 4, "_approximations": 4,
    "_adjust": 5, "_io": 6, "_report": 6, "_cli": 6,
}
EDGES = {"_io", "_report", "_cli"}


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
            if name.startswith("jaxba"):
                targets.add(name)
    return targets


def _layer(module: str) -> tuple[str, int]:
    """(folder, rank) of a module: its folder under jaxba, or the base helpers (rank 0)."""
    parts = module.split(".")
    if len(parts) == 1 or parts[1] in {"__main__", "advanced"}:
        return "jaxba", 7  # the public face (and jaxba.advanced) re-exports everything
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


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_point_down(module):
    folder, rank = _layer(module)
    upward = []
    for target in sorted(_imports(module, MODULES[module])):
        target_folder, target_rank = _layer(target)
        public_face = target == "jaxba" and folder in EDGES  # the CLI uses the public API
        if (target_rank > rank and not public_face) or (
                target_folder in EDGES and folder not in EDGES | {"jaxba"}):
            upward.append(f"{target} ({target_folder})")
    assert not upward, f"{module} ({folder}) imports upward: {', '.join(upward)}"


def test_the_check_sees_an_upward_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from ..._adjust._adjust import adjust\n")
    assert _imports("jaxba._models._cameras.bad", bad) == {"jaxba._adjust._adjust"}
    assert _layer("jaxba._adjust._adjust")[1] > _layer("jaxba._models._cameras.bad")[1]
