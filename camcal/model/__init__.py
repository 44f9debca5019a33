"""The data model: the pinhole camera, lens models, fit quality and the rig with its file."""
