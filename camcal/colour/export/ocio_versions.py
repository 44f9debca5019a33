"""OCIO profile versions: which OpenColorIO release loads a config, and a base config written for one.

An OpenColorIO release refuses a config whose ``ocio_profile_version`` is
newer than itself ("is not able to load that config version"), so a config
is written at the profile version of the oldest release it is meant for:

=========  ===============================================================
profile    hosts linking that OpenColorIO release (or a newer one)
=========  ===============================================================
2.3        Blender 4.2 LTS (OCIO 2.3.2), VFX Reference Platform CY2024
2.4        Blender 5.0, VFX Reference Platform CY2025
2.5        Blender 5.2 and 5.3 (OCIO 2.5.0), VFX Reference Platform CY2026
2.6        OpenColorIO 2.6
=========  ===============================================================

:data:`DEFAULT_PROFILE_VERSION` is 2.3: every Blender the add-on supports
(4.2 and later) and the Reference Platform's hosts of the last three years
load it.

A base config newer than the chosen version is written at that version
when it uses nothing newer (OpenColorIO's own version check, run by
``Config.validate``, names any transform style or attribute a profile
version lacks: the ACES 2 output transforms need 2.4, the "mirror
negatives" displays and interchange attributes 2.5...); otherwise one
error names what is missing. An older base keeps its own version (it
loads wherever the chosen one does). A built-in alias
(``ocio://studio-config-latest``, ``ocio://cg-config-latest``,
``ocio://default``) means the newest built-in of that family made for the
chosen version (``studio-config-v2.1.0_aces-v1.3_ocio-v2.3`` for 2.3).

References
----------
- OpenColorIO documentation, "Config syntax: ocio_profile_version" and
  the release notes of 2.3, 2.4, 2.5 and 2.6 (new built-in transforms
  and configs per release).
- VFX Reference Platform, https://vfxplatform.com (OpenColorIO 2.3.x in
  CY2024, 2.4.x in CY2025, 2.5.x in CY2026).
"""

from __future__ import annotations

import copy
import re

from camcal.base.errors import CamcalError
from camcal.colour.bake.transforms import ocio_module

__all__ = [
    "DEFAULT_PROFILE_VERSION",
    "PROFILE_VERSIONS",
    "parse_profile_version",
    "profile_version_of",
    "builtin_base_for_version",
    "at_profile_version",
]

#: The profile versions camcal writes (those the running OpenColorIO knows are a prefix of this list).
PROFILE_VERSIONS = ("2.1", "2.2", "2.3", "2.4", "2.5", "2.6")

#: Loads in Blender 4.2-5.3 and the VFX Reference Platform CY2024-CY2026 hosts.
DEFAULT_PROFILE_VERSION = "2.3"

def parse_profile_version(text: str | tuple[int, int]) -> tuple[int, int]:
    """``"2.3"`` as ``(2, 3)``, checked against :data:`PROFILE_VERSIONS` and the running OpenColorIO.

    Raises
    ------
    CamcalError
        Not a version camcal writes, or newer than the installed OpenColorIO.

    Examples
    --------
    >>> parse_profile_version("2.3")
    (2, 3)
    """
    label = text if isinstance(text, str) else ".".join(str(part) for part in text)
    if label not in PROFILE_VERSIONS:
        raise CamcalError(f"unknown OCIO profile version {label!r}, expected one of: {', '.join(PROFILE_VERSIONS)}")
    major, minor = (int(part) for part in label.split("."))
    ocio = ocio_module()
    library = tuple(int(part) for part in ocio.__version__.split(".")[:2])
    if (major, minor) > library:
        raise CamcalError(f"OCIO profile version {label} is newer than the installed OpenColorIO "
                          f"{ocio.__version__}, which cannot write it")
    return major, minor


def profile_version_of(config) -> tuple[int, int]:
    """The ``(major, minor)`` profile version of a ``PyOpenColorIO.Config``."""
    return config.getMajorVersion(), config.getMinorVersion()


def _family(name: str) -> str:
    """``studio-config-v2.1.0_aces-v1.3_ocio-v2.3`` -> ``studio-config``."""
    return re.sub(r"-v\d.*$", "", name)


def builtin_base_for_version(base: str, version: tuple[int, int]) -> str:
    """The built-in config an ``ocio://`` base means at profile ``version``.

    An alias (``-latest`` or ``default``, resolved by OpenColorIO to its
    newest built-in) becomes the newest built-in config of the same family
    whose profile version is at most ``version``; a named built-in, a file
    or ``camcal`` is returned unchanged (:func:`at_profile_version` checks
    it).

    Raises
    ------
    CamcalError
        No built-in of that family is made for ``version``.

    Examples
    --------
    >>> builtin_base_for_version("ocio://studio-config-latest", (2, 3))
    'ocio://studio-config-v2.1.0_aces-v1.3_ocio-v2.3'
    """
    if not base.startswith("ocio://"):
        return base
    ocio = ocio_module()
    resolved = ocio.ResolveConfigPath(base)
    if resolved == base:
        return base
    family = _family(resolved.removeprefix("ocio://"))
    registry = ocio.BuiltinConfigRegistry()
    fitting = []
    for name in registry:
        if _family(name) == family:
            made_for = profile_version_of(ocio.Config.CreateFromFile(f"ocio://{name}"))
            if made_for <= version:
                fitting.append((made_for, name))
    if not fitting:
        raise CamcalError(f"OpenColorIO has no built-in {family} for OCIO profile version "
                          f"{version[0]}.{version[1]}: choose a newer --ocio-version or another base")
    return f"ocio://{max(fitting)[1]}"


def at_profile_version(base, version: tuple[int, int], label: str = "the base config"):
    """A copy of ``base`` that writes at most profile ``version``; the base itself is left unchanged.

    A base at ``version`` or older is copied as it is. A newer one is set to
    ``version`` and validated: OpenColorIO refuses what that version cannot
    hold.

    Raises
    ------
    CamcalError
        The base uses a feature newer than ``version`` (OpenColorIO's
        message names it).
    """
    ocio = ocio_module()
    config = copy.deepcopy(base)
    made_for = profile_version_of(config)
    if made_for <= version:
        return config
    config.setVersion(*version)
    try:
        config.validate()
    except ocio.Exception as error:
        raise CamcalError(
            f"{label} (OCIO profile {made_for[0]}.{made_for[1]}) cannot be written at profile "
            f"{version[0]}.{version[1]}: {error} Choose a base made for {version[0]}.{version[1]} or a newer "
            f"--ocio-version (OpenColorIO {made_for[0]}.{made_for[1]} hosts load it as it is)") from None
    return config
