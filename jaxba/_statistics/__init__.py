"""Statistics of an adjusted bundle: covariance, datum, reliability, free networks, derivatives."""
