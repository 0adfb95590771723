"""The trust region shared by jaxba's Levenberg-Marquardt solvers, and their silent hook."""

import optimistix as optx

# Ceres' trust-region update: accept a step whose actual/predicted reduction ratio is at
# least 1e-3 (min_relative_decrease), grow the radius x3 above 0.75, halve it on rejection;
# first radius 1e4 (initial_trust_region_radius: λ = 1e-4 on unit-norm columns).
# optimistix's defaults (0.99, 0.01, 3.5, 0.25) from radius 1 grow the radius only when the
# model predicts the decrease to 1%: on BAL's Ladybug-49 λ then stalls (200 steps end at
# cost 13345.07; with these, 25 steps reach 13344.27), and 100 replicates of Zhang's
# calibration took a median of 19 steps (10 with these). See benchmarks/README.md.
CERES_TRUST_REGION = optx.ClassicalTrustRegion(
    high_cutoff=0.75, low_cutoff=1e-3, high_constant=3.0, low_constant=0.5)
CERES_INITIAL_RADIUS = 1e4


def silent(**info) -> None:
    """A solver `verbose` hook that reports nothing."""
    del info
