"""Run an optimistix least-squares solver one compiled step at a time, the loop in Python.

`optx.least_squares` compiles the whole loop into one program: that is what runs under
`jax.vmap`, `jax.jit` and the implicit adjoint. A single adjustment on the command line wants
each iteration printed as it completes; a host callback inside that program would do it, but
jax never stores an executable with a host callback in its persistent compilation cache, so
every process would compile the solve again. `least_squares_stepwise` runs the *same solver
object*'s `init` and `step` + `terminate` as two jitted programs without callbacks (cached like
any other) and keeps optimistix's loop rules (`optimistix._iterate`): stop when `terminate`
says so, when the iterate is not finite (`nonfinite`), or after `max_steps`
(`nonlinear_max_steps_reached`). Steps, iterates and results equal `optx.least_squares`'s.
"""

import dataclasses
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from .._memory import release_free_memory
from .._programs import returned_shapes, stored
from .._timing import CompileLog
from ._compiled import solver_jit


@dataclasses.dataclass(frozen=True)
class StepInfo:
    """What `on_step` hears after every step of a jaxba `LevenbergMarquardt`: the step
    number (0 evaluates the starting point), whether the point it evaluated was accepted,
    and the cost ½|r|² at the accepted point after the step."""

    step: int
    accepted: bool
    cost: float


def _all_finite(tree) -> jax.Array:
    leaves = jax.tree.leaves(tree)
    return jnp.all(jnp.array([jnp.all(jnp.isfinite(leaf)) for leaf in leaves]))


class _NoAux(eqx.Module):
    """`fn(y, args) -> residuals` as `fn(y, args) -> (residuals, None)` (optimistix's
    `has_aux=False`)."""

    fn: Callable

    def __call__(self, y, args):
        return self.fn(y, args), None


def _terminate(fn, solver, y, args, state):
    """terminate, the result, and whether the result is a failure (read in Python: an
    `==` on the result outside the program compiled a program of its own)."""
    terminate, result = solver.terminate(fn, y, args, {}, state, frozenset())
    result = optx.RESULTS.where(_all_finite(y), result, optx.RESULTS.nonfinite)
    return terminate, result, result != optx.RESULTS.successful


@stored("lm_init")
@solver_jit
def _init(fn, solver, y0, args):
    f_struct, aux_struct = jax.eval_shape(fn, y0, args)
    state = solver.init(fn, y0, args, {}, f_struct, aux_struct, frozenset())
    return state, *_terminate(fn, solver, y0, args, state)


@stored("lm_step")
@solver_jit
def _step(fn, solver, y, args, state):
    new_y, state, aux = solver.step(fn, y, args, {}, state, frozenset())
    # As optimistix: the finiteness test is on the iterate the step started from.
    return new_y, state, aux, *_terminate(fn, solver, y, args, state)


def compile_step_ahead(fn: Callable, solver: optx.AbstractLeastSquaresSolver, y0: Any,
                       args: Any = None, *, has_aux: bool = False) -> None:
    """Start compiling `least_squares_stepwise`'s step program for these arguments (as
    given to it) on a worker thread (`jaxba._programs.compile_ahead`): its first call then
    waits for that instead of compiling. The state's shapes from tracing `init` (no
    compilation), as the stored `init` returns them (`returned_shapes`). Nothing where
    `init` has nothing to compile (`nothing_to_compile`: run in this process, a
    re-adjustment, or stored by an earlier one: the step with it)."""
    if not has_aux:
        fn = _NoAux(fn)
    if _init.nothing_to_compile(fn, solver, y0, args):
        return
    state, *_ = eqx.filter_eval_shape(_init.__wrapped__.nested, fn, solver, y0, args)
    _step.ahead(fn, solver, y0, args, returned_shapes(state))


def _stops(terminate, failed) -> bool:
    return bool(terminate) or bool(failed)


def least_squares_stepwise(
    fn: Callable,
    solver: optx.AbstractLeastSquaresSolver,
    y0: Any,
    args: Any = None,
    *,
    has_aux: bool = False,
    max_steps: int,
    on_step: Callable[[StepInfo], None] | None = None,
) -> optx.Solution:
    """`optx.least_squares(fn, solver, y0, args, has_aux=has_aux, max_steps=max_steps,
    throw=False)` with the loop in Python; `on_step(StepInfo)` is called after every step.

    `fn(y, args) -> residuals` (`-> (residuals, aux)` with `has_aux`) must be a
    module-level function (it is a static argument of the compiled step). `on_step` reads
    `num_accepted_steps` and `cost` of the solver's state (jaxba's `LevenbergMarquardt`).
    Not for use under jit or vmap: use `optx.least_squares` there.
    """
    if not has_aux:
        fn = _NoAux(fn)
    with CompileLog() as log:
        state, terminate, result, failed = _init(fn, solver, y0, args)
    if log.count:
        release_free_memory()  # what compiling `_init` freed, before `_step` compiles
    y, aux = y0, state.aux
    num_steps = 0
    while num_steps < max_steps and not _stops(terminate, failed):
        accepted_before = int(state.num_accepted_steps)
        y, state, aux, terminate, result, failed = _step(fn, solver, y, args, state)
        num_steps += 1
        if on_step is not None:
            accepted = int(state.num_accepted_steps) > accepted_before
            on_step(StepInfo(num_steps - 1, accepted, float(state.cost)))
    ran_out = not bool(failed) and not bool(terminate)
    if ran_out:
        result = optx.RESULTS.nonlinear_max_steps_reached
    y, aux, stats = solver.postprocess(fn, y, aux, args, {}, state, frozenset(), result)
    return optx.Solution(
        value=y, result=result, aux=aux, state=state,
        stats={"num_steps": jax.device_put(num_steps), "max_steps": max_steps, **stats},
    )
