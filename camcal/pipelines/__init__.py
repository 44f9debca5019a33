"""Paths in, files out: the steps the CLI calls (calibrate, solve, batch, undistort, rectify, colour)."""
