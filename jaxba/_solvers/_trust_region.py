"""The trust-region loop shared by jaxba's Levenberg-Marquardt solvers, as an optimistix solver.

`optx.AbstractGaussNewton` linearises the residual function (`jax.linearize`) at every trial
point and carries the linearisation in its state, only to predict the trust region's
reduction with one Jacobian-vector product. jaxba's descents already hold the Gauss-Newton
model in their normal equations (JᵀJ and Jᵀr, from per-row Jacobian blocks), so
`LevenbergMarquardt` evaluates nothing but the residuals at a trial point and asks the
descent for the predicted reduction: for Zhang-size calibrations the linearisation was a
third of every step. It is an `optx.AbstractLeastSquaresSolver`, driven by
`optx.least_squares` (and so differentiable by its implicit adjoint).

Per step: evaluate the residuals at the trial point y + δ; accept it when the actual
reduction is at least `low_cutoff` of the predicted one (a trial point with non-finite cost
is rejected), grow the radius x`high_constant` above `high_cutoff`, divide it on rejection by
a factor that starts at 1/`low_constant` and doubles with every consecutive rejection
(`TrustRegionUpdate`; Ceres' rejection rule and min_relative_decrease, with a fixed growth
x3 for a good model where Ceres grows by a ratio-dependent factor); at an accepted point the
descent linearises (`query`: the Jacobian-dependent work), then proposes the damped step
for the current radius (`solve` with λ = 1/radius: the damping-dependent work), or with
`step_tolerance` the Gauss-Newton step first (below). Where the step to it ends the solve
(the Cauchy or the function-tolerance test), neither runs: BAL's solves end that way, and
their last linearisation and solve were an eighth of Dubrovnik-16's time (8 -> 7 of each).

Stops as converged at an accepted point from which the Gauss-Newton step would move every
unknown by less than `step_tolerance` of its standard deviation (the statistical test below;
or where that step would lower the cost by less than its rounding, `COST_RESOLUTION`),
where optimistix's Cauchy test passes (the step and the residual change within rtol/atol
elementwise), where the step to it lowered the cost by at most `function_tolerance` times the
cost before it (Ceres' function tolerance), or when the radius falls below `MIN_RADIUS`
(every step, however short, is rejected: Ceres' `min_trust_region_radius`, also a
convergence). A non-finite cost or damped step, or `max_steps`, ends the solve unconverged.

The statistical test. With e the whitened residuals (σ0 = 1), N = JᵀJ and g = Jᵀe at the
accepted point, the unknowns' cofactors are Q = N⁻¹ (Cxx = σ0² Q) and the Gauss-Newton step
Δ = -N⁻¹g has the Mahalanobis length ΔᵀNΔ = gᵀN⁻¹g (the descent's `solve` with λ = 0). By
Cauchy-Schwarz in the metric of N, |Δ_i| ≤ √((N⁻¹)_ii) √(ΔᵀNΔ) for every unknown i, so

    gᵀN⁻¹g ≤ τ²   implies   |Δ_i| ≤ τ σ0 √Q_ii   for all i at once,

without forming any diagonal of N⁻¹ (which the Schur backend cannot afford per iterate). It
is a decrement test with an absolute threshold: invariant to the scaling of the unknowns
(the dense backend's Jacobi-scaled z, the Schur backend's raw units), the same for both
backends, and it needs no redundancy, so padded batches stop as their members would alone.
σ is the a priori σ0 √Q_ii; the reported σ̂0 √Q_ii differ by σ̂0/σ0 (about 1 for a
well-weighted adjustment; 0.24 for Zhang's calibration at σ = 1 px, where the test then
holds to τ/0.24 of the reported σ). The bound is near tight where the remaining error lies
along one weak direction: on the 60-image close-range block of benchmarks/blocks.py, at an
iterate with √(gᵀN⁻¹g)/σ̂0 = 3.844e-4, max_i |Δ_i|/σ̂_i = 3.840e-4. It looks ahead: the
solve ends at the iterate whose next step would be negligible, not after taking that step.

The Gauss-Newton steps. Levenberg-Marquardt's damping slows the weak directions down (on
that block the error fell ~10x per step from 0.24 σ, from a damping that shrinks 3x per step;
a free network held by a minimal datum took 12 steps), so at every accepted point the loop
first proposes the undamped Gauss-Newton step Δ; the trust region judges it like any other
(ratio of actual to predicted reduction). A rejected Gauss-Newton step costs one step and
nothing else: the damped step for the same radius is tried next from the same point, as if
the Gauss-Newton step had not been proposed (no shrink of the radius), and from then on
the Gauss-Newton step is proposed only where it is 10x shorter in gᵀN⁻¹g than the one that
failed (`GAUSS_NEWTON_RETREAT`), and always within `GAUSS_NEWTON_REGION` (gᵀN⁻¹g ≤ 1: 1 σ0
in every unknown, where the linear model is excellent). At an accepted point the undamped
solve comes first (it also gives the stopping test's gᵀN⁻¹g), the damped one only where its
step is the one proposed (`_propose`). Measured (benchmarks/README.md): the 60-image block 6 -> 5
steps (4 accepted, as Ceres' 4 iterations, iteration 0 included), with a free datum 12 -> 5,
Zhang's calibration 8 -> 7, DBAT's 8 -> 7, the lab 6 -> 5, the free network of 115 images
5 -> 4; the Gauss-Newton step was accepted wherever it was proposed on these. Proposed only
within gᵀN⁻¹g ≤ 1e4 instead, it failed 6 times on the free-datum block (16 steps).

`STEP_TOLERANCE` τ = 1e-5, measured (benchmarks/README.md) when the Gauss-Newton step was
proposed only within GAUSS_NEWTON_REGION: on the block above the solve ended after 6 steps
for τ = 1e-4 and 1e-5 alike (the last Gauss-Newton step lands far
inside), 9 with the former cost-change rule; τ = 1e-6 reaches the cost's rounding floor
there (14 steps, most rejected). On Zhang's calibration τ = 1e-3 would stop 1.2e-3 σ̂ from
the maximum-likelihood optimum and move a printed digit that the optimum reproduces
(tests/test_zhang.py); τ = 1e-5 stops within 2e-6 σ̂.
"""

import abc
from collections.abc import Callable
from typing import Any, Generic, TypeVar

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int, PyTree, Scalar

Y = TypeVar("Y")
DescentState = TypeVar("DescentState")

# Ceres' first radius (initial_trust_region_radius): λ = 1e-4 on unit-norm columns.
CERES_INITIAL_RADIUS = 1e4
# Below this radius, stop (Ceres' min_trust_region_radius).
MIN_RADIUS = 1e-32
# Ceres' default function_tolerance: stop once an accepted step lowers the cost by at most
# this fraction of it (`jaxba bal`, and the "cost" stopping rule of `jaxba._solvers._solve`).
CERES_FUNCTION_TOLERANCE = 1e-6
# τ of the "cost" rule's guard: Ceres' test passes where the damped steps stall, too. On
# Ladybug-49 imported as a project (omega-phi-kappa poses, which the damped steps cross more
# slowly than BAL's Rodrigues vectors) it passed at a cost of 13345.07, 0.8 above `jaxba
# bal`'s (~1.3 σ; the damped steps alone then crawled on for 50 steps); on Dubrovnik-16 it
# passes at gᵀN⁻¹g = 3.3e-7 (6e-4 σ).
COST_RULE_STEP_TOLERANCE = 1e-3
# τ of the statistical test (module docstring): stop where the Gauss-Newton step would move
# every unknown by at most 1e-5 of its (a priori) σ, far below anything a report prints.
STEP_TOLERANCE = 1e-5
# Below this fraction of the cost, the Gauss-Newton step's predicted reduction ½gᵀN⁻¹g is
# rounding: the cost sums n squares, so it carries a relative error of ~√n ε (3e-14 for
# n = 2e4). On the 115-image free network of benchmarks/blocks.py, solved with a minimal
# datum, the cost (9748.29, 19,502 residuals) stopped changing at gᵀN⁻¹g = 1.12e-10 > τ²
# (½gᵀN⁻¹g = 5.8e-15 of the cost), and 17 rejected steps followed until the radius floor.
# It binds only where cost > τ²/(2e-14) = 5000, i.e. r > ~1e4 observations, and then at
# gᵀN⁻¹g ≈ 1e-14 r σ̂0²: every unknown within 1e-7 √r of its σ (3e-5 σ for the 60-image
# block's r = 101,576).
COST_RESOLUTION = 1e-14
# Where the Gauss-Newton step is at most this long (gᵀN⁻¹g, whitened: 1 σ0 in every
# unknown), always propose it (module docstring: the Gauss-Newton steps); farther out until
# one fails.
GAUSS_NEWTON_REGION = 1.0
# After a rejected Gauss-Newton step with decrement D, propose it only where gᵀN⁻¹g ≤ this
# times D (and within GAUSS_NEWTON_REGION).
GAUSS_NEWTON_RETREAT = 0.1


class TrustRegionUpdate(eqx.Module):
    """Accept a step whose actual/predicted reduction ratio is at least `low_cutoff`, grow
    the radius x`high_constant` above `high_cutoff`; on rejection multiply it by
    `low_constant`, squared after two consecutive rejections, cubed... (Ceres doubles its
    decrease factor with each one, so that a hopeless point gives up in ~16 steps instead of
    ~120). Defaults: Ceres' min_relative_decrease 1e-3, x3 for a good model, halving.
    optimistix's defaults (0.99, 0.01, 3.5, 0.25, from radius 1) grow the radius only when
    the model predicts the decrease to 1 %: on BAL's Ladybug-49 λ then stalls (200 steps
    end at cost 13345.07; with these, 25 steps reach 13344.27); see benchmarks/README.md."""

    high_cutoff: float = 0.75
    low_cutoff: float = 1e-3
    high_constant: float = 3.0
    low_constant: float = 0.5


class AbstractNormalDescent(eqx.Module, Generic[Y, DescentState]):
    """The linear algebra of a Levenberg-Marquardt solver: a Gauss-Newton model of ½|r|²
    held as normal equations, and its damped steps."""

    @abc.abstractmethod
    def init(self, y: Y, residual: PyTree[Array]) -> DescentState:
        """A state of the right structure (`residual`: zeros of the residuals' shape)."""

    @abc.abstractmethod
    def query(self, y: Y, residual: PyTree[Array], state: DescentState) -> DescentState:
        """Linearise at the accepted point `y`, where the residuals are `residual`."""

    @abc.abstractmethod
    def solve(self, damping: Scalar, state: DescentState) -> tuple[Y, Scalar, optx.RESULTS]:
        """The step -(N + λD)⁻¹g at the accepted point of the last `query` (N = JᵀJ,
        g = Jᵀr, D the descent's damping diagonal, λ = `damping`), gᵀ(N + λD)⁻¹g, and the
        step's result. The loop damps with λ = 1 / radius; λ = 0 asks for the Gauss-Newton
        step -N⁻¹g, whose gᵀN⁻¹g (the Gauss-Newton decrement) `step_tolerance` tests."""

    @abc.abstractmethod
    def predicted_reduction(self, y_diff: Y, state: DescentState) -> Scalar:
        """The model's change of the cost for the step `y_diff`, ½|r + Jδ|² - ½|r|² =
        δᵀJᵀr + ½ δᵀJᵀJδ (negative for a descent step)."""


def _all_finite(tree) -> Bool[Array, ""]:
    return jnp.all(jnp.array([jnp.all(jnp.isfinite(leaf)) for leaf in jax.tree.leaves(tree)]))


def finite_step(step: Y) -> tuple[Y, optx.RESULTS]:
    """A descent's step and its result: `singular` (and a zero step) where the damped
    system gave non-finite values (a dense Cholesky of JᵀJ + λI fails only on NaNs)."""
    finite = _all_finite(step)
    result = optx.RESULTS.where(finite, optx.RESULTS.successful, optx.RESULTS.singular)
    return jax.tree.map(lambda leaf: jnp.where(finite, leaf, 0.0), step), result


def normal_equations_result(normal) -> optx.RESULTS:
    """`singular` where the normal equations hold non-finite values (a non-finite Jacobian
    at an accepted point: no step can help), else successful. A Schur step that is not
    finite for finite normal equations (S barely positive definite at a tiny damping) is
    left to the trust region, which rejects it and shrinks the radius."""
    return optx.RESULTS.where(
        _all_finite(normal), optx.RESULTS.successful, optx.RESULTS.singular)


def _cost(residual: PyTree[Array]) -> Scalar:
    return 0.5 * sum(jnp.sum(r**2) for r in jax.tree.leaves(residual))


def _tree_sub(a, b):
    return jax.tree.map(lambda x, y: x - y, a, b)


class _LevenbergMarquardtState(eqx.Module, Generic[Y, DescentState]):
    first_step: Bool[Array, ""]
    y_eval: Y  # the trial point of the next step
    residual: PyTree[Array]  # at the accepted point
    cost: Float[Array, ""]  # ½|residual|²
    aux: Any
    radius: Float[Array, ""]
    shrink: Float[Array, ""]  # factor of the next rejection: low_constant^(k+1) after k in a row
    gauss_newton: Bool[Array, ""]  # y_eval is the Gauss-Newton step ...
    decrement: Float[Array, ""]  # ... whose gᵀN⁻¹g this is
    region: Float[Array, ""]  # propose the Gauss-Newton step where gᵀN⁻¹g ≤ region
    descent_state: DescentState
    terminate: Bool[Array, ""]
    result: optx.RESULTS
    num_steps: Int[Array, ""]
    num_accepted_steps: Int[Array, ""]


class LevenbergMarquardt(optx.AbstractLeastSquaresSolver):
    """Levenberg-Marquardt with an `AbstractNormalDescent`; see the module docstring.

    `rtol`, `atol`, `norm`: optimistix's Cauchy termination; `step_tolerance`: τ of the
    statistical test, stop where the descent's Gauss-Newton decrement gᵀN⁻¹g is at most τ²,
    with the Gauss-Newton steps (0: both off, as for BAL; jaxba's bundle solvers use
    `STEP_TOLERANCE`); `function_tolerance`: stop once an accepted step lowers the cost by
    at most this fraction (0: off); `gauss_newton` False (with `step_tolerance` > 0): the
    statistical test and the Gauss-Newton step only at points where the step to them passed
    the function tolerance, damped steps elsewhere: the solve stops where both tests hold,
    and where only Ceres' test does (the damped steps stalled) tries the Gauss-Newton step
    (the "cost" rule of `jaxba._solvers._solve.stopping_rule`);
    `initial_radius`: the first trust-region radius (1/λ in the descent's units); `update`:
    the radius rule. No callback inside: `jaxba._solvers._steps.least_squares_stepwise` runs the
    loop from Python where each step should be reported.
    """

    rtol: float
    atol: float
    descent: AbstractNormalDescent
    norm: Callable[[PyTree], Scalar] = optx.max_norm
    step_tolerance: float = 0.0
    function_tolerance: float = 0.0
    gauss_newton: bool = True
    initial_radius: float = CERES_INITIAL_RADIUS
    update: TrustRegionUpdate = TrustRegionUpdate()

    def init(self, fn, y, args, options, f_struct, aux_struct, tags) -> _LevenbergMarquardtState:
        del fn, args, options, tags
        residual = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), f_struct)
        dtype = jax.tree.leaves(f_struct)[0].dtype
        return _LevenbergMarquardtState(
            first_step=jnp.array(True),
            y_eval=y,
            residual=residual,
            cost=jnp.array(jnp.inf, dtype),
            aux=jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), aux_struct),
            radius=jnp.array(self.initial_radius, dtype),
            shrink=jnp.array(self.update.low_constant, dtype),
            gauss_newton=jnp.array(False),
            decrement=jnp.array(jnp.inf, dtype),
            region=jnp.array(jnp.inf, dtype),
            descent_state=self.descent.init(y, residual),
            terminate=jnp.array(False),
            result=optx.RESULTS.successful,
            num_steps=jnp.array(0),
            num_accepted_steps=jnp.array(0),
        )

    def step(self, fn, y, args, options, state: _LevenbergMarquardtState, tags):
        del options, tags
        residual_eval, aux_eval = fn(state.y_eval, args)
        cost_eval = _cost(residual_eval)
        y_diff = _tree_sub(state.y_eval, y)
        predicted = self.descent.predicted_reduction(y_diff, state.descent_state)
        actual = cost_eval - state.cost
        update = self.update
        accept = state.first_step | ((predicted < 0) & (actual <= update.low_cutoff * predicted))
        good = ~state.first_step & (predicted < 0) & (actual < update.high_cutoff * predicted)
        # A rejected Gauss-Newton step says nothing about the radius of the damped steps:
        # the damped step for the same radius is tried next, as if it had not been proposed.
        missed = ~accept & state.gauss_newton
        factor = jnp.where(accept, jnp.where(good, update.high_constant, 1.0),
                           jnp.where(missed, 1.0, state.shrink))
        radius = jnp.where(state.first_step, state.radius, factor * state.radius)
        shrink = jnp.where(accept, update.low_constant,
                           jnp.where(missed, state.shrink, state.shrink * update.low_constant))
        region = jnp.where(missed, jnp.maximum(GAUSS_NEWTON_RETREAT * state.decrement,
                                               GAUSS_NEWTON_REGION), state.region)

        cauchy = self._cauchy_test(
            state.y_eval, y_diff, residual_eval, _tree_sub(residual_eval, state.residual))
        small_change = state.cost - cost_eval <= self.function_tolerance * state.cost
        # Where accepted, the solve ends; without `gauss_newton` a small change only asks
        # for the statistical test (`propose`). (With a function tolerance of 0 no accepted
        # step is a small change.)
        guarded = self.step_tolerance > 0 and not self.gauss_newton
        last = (cauchy if guarded else cauchy | small_change) & ~state.first_step

        def linearised(descent_state):  # accepted, and the solve goes on
            descent_state = self.descent.query(state.y_eval, residual_eval, descent_state)
            return state.y_eval, residual_eval, cost_eval, aux_eval, descent_state, jnp.array(False)

        def unchanged(descent_state):  # rejected, or accepted where the solve ends
            def pick(new, old):
                return jax.tree.map(lambda a, b: jnp.where(accept, a, b), new, old)

            return (pick(state.y_eval, y), pick(residual_eval, state.residual),
                    jnp.where(accept, cost_eval, state.cost), pick(aux_eval, state.aux),
                    descent_state, accept | (radius < MIN_RADIUS))

        # Where the solve ends nothing reads the model at the point: no linearisation. (One
        # cond with the state passed through one branch; passed through a cond nested in a
        # branch, or a switch, XLA copied it every step.)
        y, residual, cost, aux, descent_state, terminate = jax.lax.cond(
            accept & ~last, linearised, unchanged, state.descent_state)
        result = optx.RESULTS.where(
            jnp.isfinite(cost), optx.RESULTS.successful, optx.RESULTS.nonfinite)

        def propose():  # the step for the next trial, and whether the solve has converged
            if self.step_tolerance > 0:  # without `gauss_newton`, where Ceres' test passed
                tested = accept if self.gauss_newton else (
                    accept & small_change & ~state.first_step)
                return self._propose(y, tested, radius, descent_state, cost, region)
            step, _, step_result = self.descent.solve(1.0 / radius, descent_state)
            return (step, step_result, jnp.array(False), jnp.array(False),
                    jnp.array(jnp.inf, cost.dtype))

        def stop():  # no trial follows (the solve ends here): no solve for one
            return (jax.tree.map(jnp.zeros_like, y), optx.RESULTS.successful, jnp.array(False),
                    jnp.array(False), jnp.array(jnp.inf, cost.dtype))

        going_on = (result == optx.RESULTS.successful) & ~terminate
        y_descent, descent_result, converged, gauss_newton, decrement = jax.lax.cond(
            going_on, propose, stop)
        terminate = terminate | converged
        result = optx.RESULTS.where(going_on & ~converged, descent_result, result)
        state = _LevenbergMarquardtState(
            first_step=jnp.array(False),
            y_eval=jax.tree.map(lambda a, b: a + b, y, y_descent),
            residual=residual,
            cost=cost,
            aux=aux,
            radius=radius,
            shrink=shrink,
            gauss_newton=gauss_newton,
            decrement=decrement,
            region=region,
            descent_state=descent_state,
            terminate=terminate | (result != optx.RESULTS.successful),
            result=result,
            num_steps=state.num_steps + 1,
            num_accepted_steps=state.num_accepted_steps + jnp.where(accept, 1, 0),
        )
        return y, state, aux

    def _propose(self, y, accept, radius, descent_state, cost, region):
        """The next trial step and its result; whether the solve has converged; whether the
        step is the Gauss-Newton one, and gᵀN⁻¹g (inf where not computed).

        At a point just linearised (`accept`) with `cost` the Gauss-Newton step Δ = -N⁻¹g
        and gᵀN⁻¹g come first (`descent.solve` with λ = 0): converged where gᵀN⁻¹g ≤ τ²
        or where the step's predicted reduction is below the cost's resolution, ½gᵀN⁻¹g ≤
        `COST_RESOLUTION` cost; Δ is proposed where it is finite and gᵀN⁻¹g ≤ `region`.
        The damped step for `radius` (λ = 1 / radius) is solved only where Δ is not
        proposed. The (at most) two solves are rounds of one loop, so the solve, the
        largest part of the step, is compiled once: the dense step of a 140-unknown
        calibration compiled in 2.6 s with two copies of it (XLA -O0).
        """
        tolerance = jnp.maximum(self.step_tolerance**2, 2 * COST_RESOLUTION * cost)
        damped = 1.0 / radius

        def solve(carry):
            round_, _, _, decrement, _ = carry
            undamped = accept & (round_ == 0)
            step, value, result = self.descent.solve(
                jnp.where(undamped, 0.0, damped), descent_state)
            decrement = jnp.where(undamped, value, decrement)
            near = undamped & (decrement <= jnp.maximum(region, tolerance)) & _all_finite(step)
            return round_ + 1, step, result, decrement, near

        def again(carry):  # the damped solve after a Gauss-Newton step that is not proposed
            round_, _, _, _, near = carry
            return (round_ == 0) | ((round_ == 1) & accept & ~near)

        start = (jnp.array(0), jax.tree.map(jnp.zeros_like, y),  # a step has y's structure
                 optx.RESULTS.successful, jnp.array(jnp.inf, cost.dtype), jnp.array(False))
        _, step, result, decrement, near = jax.lax.while_loop(again, solve, start)
        converged = accept & (decrement <= tolerance)
        result = optx.RESULTS.where(near, optx.RESULTS.successful, result)
        return step, result, converged, near, decrement

    def _cauchy_test(self, y, y_diff, residual, residual_diff) -> Bool[Array, ""]:
        """optimistix's Cauchy termination: |Δy| < atol + rtol |y| and |Δr| < atol + rtol
        |r|, elementwise in `norm`."""

        def small(x, dx):
            return self.norm(jax.tree.map(
                lambda a, da: jnp.abs(da) / (self.atol + self.rtol * jnp.abs(a)), x, dx)) < 1

        return small(y, y_diff) & small(residual, residual_diff)

    def terminate(self, fn, y, args, options, state: _LevenbergMarquardtState, tags):
        del fn, y, args, options, tags
        return state.terminate, state.result

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        del fn, args, options, state, tags, result
        return y, aux, {}
