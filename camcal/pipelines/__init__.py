"""Pipelines: paths in, files out; each step a function the CLI calls."""
