"""Lazy package exports (PEP 562): a name is imported from its module when first used.

`import jaxba` and the command line's input checks then run without importing jax (over a
second on a small machine): bad input is reported before jax is loaded.
"""

import importlib
from collections.abc import Callable, Mapping

from ._gc import paused_gc


def lazy_exports(
    package: str, exports: Mapping[str, tuple[str, ...]]
) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """`__getattr__`, `__dir__` and `__all__` for `package`, whose `exports` map a module
    name, relative to `package` (".\\_solve") or absolute, to the public names it defines."""
    if any(isinstance(names, str) for names in exports.values()):
        raise TypeError("lazy_exports: each module maps to a tuple of names, not a string")
    where = {name: module for module, names in exports.items() for name in names}
    namespace = importlib.import_module(package).__dict__

    def __getattr__(name: str) -> object:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        with paused_gc():  # imports make no garbage; the collector's passes walked jax's
            module = importlib.import_module(where[name], package)  # objects (~0.1 s)
        value = getattr(module, name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *where})

    return __getattr__, __dir__, sorted(where)
