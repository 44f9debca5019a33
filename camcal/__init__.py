"""camcal: geometric and colour camera calibration for VFX pipelines."""

__version__ = "0.1.0"

__all__ = ["__version__"]
