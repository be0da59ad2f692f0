"""Harness: CLI, device selection, runner, frame cache, reference, metrics and results."""
