"""`solver_jit`: the solvers' loops compiled with XLA options of their own.

The options travel with each program (`jax.jit(compiler_options=...)`); jax's global
configuration stays the caller's.

YNNPACK's reductions. XLA:CPU (jaxlib 0.10.2) hands dot products and reductions to YNNPACK
by default. The solvers reduce float64 arrays over short axes (a 3 x 9 block times a vector
per observation, the gradient's 2 x 9 blocks, the cost), where YNNPACK's reductions ran
slower than XLA's own fused loops. Without them, its dot products kept (CPU seconds, best
of 7, machine loaded): Dubrovnik-16's solve 0.61-0.63 -> 0.55-0.57 s; the close-range
block of benchmarks/blocks.py, normal equations 60 -> 41 ms, the compiled solve 0.54 ->
0.43 s.

The older LLVM IR emitters. XLA:CPU compiles each fusion of a program into a kernel of its
own; its MLIR fusion emitters (the default) cost ~35 ms of CPU per kernel, the older LLVM IR
emitters about half that, and the Schur backend's programs hold hundreds of kernels (the
step of Dubrovnik-16 imported as a project: 285). Without them (CPU seconds under load 4-7,
one process, the same run): Dubrovnik-16's BAL solve compiles in 7.6-7.9 s instead of
11.2-12.9 s to the same cost (0.90-1.08 s of CPU either way under that load; on a quiet
machine the solves of Dubrovnik-16 and Ladybug-49 run 10-15 % slower with them); `jaxba
adjust` of the imported project compiles its seven programs in 12.4 s instead of 20.5 s.
So the programs run once or a few times per adjustment (the stepwise loop's steps, normal
equations, cofactors) take them, and the solve compiled as one loop (`jaxba bal`, the BAL
benchmarks: run time is what is measured there, from a warm cache) keeps XLA's default
emitters (`solver_jit(fn, fusion_emitters=True)`).
"""

import functools
from collections.abc import Callable

import equinox as eqx
import jax

# YNNPACK for individual dot products only (not its reductions); the LLVM IR emitters.
SOLVER_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type": "LIBRARY_FUSION_TYPE_INDIVIDUAL_DOT",
                  "xla_cpu_use_fusion_emitters": False}


@functools.cache
def solver_compiler_options(fusion_emitters: bool = False) -> dict[str, str | bool]:
    """`SOLVER_OPTIONS` where this jaxlib accepts them (a trivial program compiled once to
    find out), else none: the names are XLA's experimental ones. `fusion_emitters`: XLA's
    default (MLIR) emitters, YNNPACK's option alone."""
    try:
        jax.jit(lambda x: x + 1, compiler_options=SOLVER_OPTIONS).lower(1.0).compile()
    except jax.errors.JaxRuntimeError:
        return {}
    if fusion_emitters:
        return {k: v for k, v in SOLVER_OPTIONS.items() if k != "xla_cpu_use_fusion_emitters"}
    return dict(SOLVER_OPTIONS)


class solver_jit:  # noqa: N801 (used as a decorator, like eqx.filter_jit)
    """`eqx.filter_jit(fn)` compiled with `solver_compiler_options(fusion_emitters)`, settled
    at the first call or `lower` (never at import). Calls and `lower` as `eqx.filter_jit`'s.

    Only for programs called at the top level, never inside `jax.jit` or `jax.vmap` (jax
    refuses compiler options on a nested jit): the Schur backend's solve, normal equations
    and cofactors, the stepwise loop's steps, the batch's program and the inner-constraint
    datum move, whose arguments are built in NumPy or driven from Python anyway. Inside
    another program (a stored export, `nested`) the options go to that program. The dense
    solve, which batches vmap, keeps the default options.
    """

    def __init__(self, fn: Callable, *, fusion_emitters: bool = False):
        self._fn = fn
        self._fusion_emitters = fusion_emitters
        self._program = None
        functools.update_wrapper(self, fn)

    def _compiled(self):
        if self._program is None:
            self._program = eqx.filter_jit(self._fn, compiler_options=self.compiler_options())
        return self._program

    def __call__(self, *args, **kwargs):
        return self._compiled()(*args, **kwargs)

    def lower(self, *args, **kwargs):
        return self._compiled().lower(*args, **kwargs)

    @functools.cached_property
    def nested(self):
        """`fn` jitted without the options, to trace inside another program (an export:
        `jaxba._programs.call_stored` compiles that with `compiler_options()`)."""
        return eqx.filter_jit(self._fn)

    def compiler_options(self) -> dict[str, str | bool]:
        return solver_compiler_options(self._fusion_emitters)
