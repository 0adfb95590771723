"""Statistics of an adjusted bundle: covariance, datum, reliability, free networks, derivatives;
the result by ID and its summary."""
