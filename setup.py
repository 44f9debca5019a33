"""Packaging beside pyproject.toml: the add-on and OCIO templates ship inside the wheel.

``addon/`` and ``ocio_configs/`` stay top-level folders of the repository
and become the packages ``camcal.resources.addon`` and
``camcal.resources.ocio_configs`` (found with importlib.resources).
"""

from setuptools import find_packages, setup

RESOURCES = {"camcal.resources.addon": "addon", "camcal.resources.ocio_configs": "ocio_configs"}

setup(
    packages=find_packages(include=["camcal*"]) + list(RESOURCES),
    package_dir=RESOURCES,
    package_data={"camcal.resources.addon": ["*.toml", "*.md"], "camcal.resources.ocio_configs": ["*.ocio"]},
)
