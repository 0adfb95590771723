"""Orchestration: datum -> solve -> statistics, re-adjustments, batches, Monte Carlo."""
