"""Estimators: one module per estimator, each with its OpenCL kernel beside it."""
