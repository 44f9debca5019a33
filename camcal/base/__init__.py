"""Primitives that import nothing else of camcal: errors, progress, atomic writes, JSON files, fields, limits, frame ranges, the provenance clock, the optional dependencies."""
