"""Project files in, BundleProblem out; plain Python around the jitted core.

Reading (`read_project`, the specs, `ProjectError`) needs no jax; building, completing
(missing approximations computed) and adjusting are imported when first used.
"""

from ..._lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "._build": ("Project", "build_project"),
    "._complete": ("Completion", "complete_project"),
    "._deferred": ("Deferral", "adjust_deferred"),
    "._errors": ("ProjectError",),
    "._readers": ("read_project",),
    "._run": ("adjust_project",),
    "._spec": ("AdjustmentSettings", "ProjectSpec"),
    "._write": ("write_project",),
})
