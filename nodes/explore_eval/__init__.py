"""Evaluator of an active exploration run: coverage, travel, rotation, RMSE, prediction miss."""
