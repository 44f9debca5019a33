"""Pure camera geometry: arrays and dataclasses in and out, never a path or a file.

Boards (``board``), straight lines and the plumb-line fit (``lines``, ``plumbline``),
DLT and Zhang calibration (``dlt``, ``zhang``), the bundle adjustment (``bundle``),
its jackknife (``jackknife``), self-calibration on a structure-from-motion seed
(``selfcal``, ``sfm``), undistortion, remap and ST-maps (``undistort``, ``remap``,
``stmap``), rectification (``rectify``) and correspondences (``correspondence``).
"""
