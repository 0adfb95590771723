"""The trust-region Levenberg-Marquardt loop and its normal-equation backends (Dense, Schur)."""
