"""The Schur backend: Levenberg-Marquardt of a `BundleProblem` with the object points
eliminated (reduced camera matrix assembled pair-wise), and its statistics."""
