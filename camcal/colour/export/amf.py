"""An ACES Metadata File (AMF 2.0) that names a camera's input transform, so it is applied once.

:func:`amf_text` writes an ``aces:acesMetadataFile`` (namespace
``urn:ampas:aces:amf:v2.0``) whose pipeline holds one
``aces:inputTransform``: the camera's CLF (:func:`camcal.colour.export.aces.clf_text`)
referenced as an external file (the AMF specification's "custom IDT (e.g.
CLF)"), its SHA-256 in ``aces:hash`` so a reader can tell the file has not
changed, its ACES transform ID and what it is in ``aces:description``, and
the ``applied`` attribute: ``false`` while the images are camera code values
(the AMF is the recipe), ``true`` once the transform is baked into them
(e.g. ACES2065-1 pulls): a reader then does not apply it again.

The elements follow the AMF 2.0 schema (``acesMetadataFile.xsd`` of the
Academy's ``aces-amf`` repository) in its order: ``amfInfo`` (description,
dateTime, uuid), then ``pipeline`` with ``pipelineInfo`` (description,
dateTime, uuid, the ACES ``systemVersion``) and the ``inputTransform``
(description, hash, file). The schema lets an input transform be named by
*one* of ``uuid``, ``file`` or ``transformId``; a transform ID that is not
in the Academy's registry is "a custom or unknown transform" a reader cannot
apply, so the file is the reference and the ID is in the description (and
in the CLF's own ``Info``).

References
----------
- ACES Metadata File (AMF) specification v2.0 and its implementation guide
  (ACES 2 documentation): the ``applied`` attribute, custom input transforms.
- ISO 8601 / XML Schema ``xs:dateTime``; RFC 4122 UUIDs (``urn:uuid:``).
"""

from __future__ import annotations

import base64
import re
import uuid
import xml.etree.ElementTree as ET
from urllib.parse import quote

from camcal.base.errors import CamcalError
from camcal.colour.export.aces import InputTransform

__all__ = ["AMF_NAMESPACE", "AMF_VERSION", "ACES_SYSTEM_VERSION", "SHA256_ALGORITHM", "amf_text"]

AMF_NAMESPACE = "urn:ampas:aces:amf:v2.0"
AMF_VERSION = "2.0"
#: The ACES system release the pipeline is for (major, minor, patch).
ACES_SYSTEM_VERSION = (2, 0, 0)
SHA256_ALGORITHM = "http://www.w3.org/2001/04/xmlenc#sha256"
_DATE_TIME = re.compile(r"\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(\.\d+)?(Z|[+-]\d{2}:\d{2})")


def _element(parent: ET.Element, name: str, text: str | None = None, **attributes: str) -> ET.Element:
    node = ET.SubElement(parent, f"{{{AMF_NAMESPACE}}}{name}", attributes)
    if text is not None:
        node.text = text
    return node


def _info(parent: ET.Element, name: str, description: str, created: str, identity: uuid.UUID) -> ET.Element:
    info = _element(parent, name)
    _element(info, "description", description)
    when = _element(info, "dateTime")
    _element(when, "creationDateTime", created)
    _element(when, "modificationDateTime", created)
    _element(info, "uuid", identity.urn)
    return info


def amf_text(transform: InputTransform, clf_path: str, clf_sha256: bytes, created: str, *,
             applied: bool = False) -> str:
    """The AMF 2.0 text naming ``transform``'s CLF as the pipeline's input transform.

    Parameters
    ----------
    transform
        The input transform (to ACES2065-1: an AMF's input transform ends in ACES).
    clf_path
        The CLF as the AMF refers to it: a path relative to the AMF's folder,
        ``/``-separated (written as a URI, percent-encoded).
    clf_sha256
        The 32-byte SHA-256 digest of the CLF file's bytes.
    created
        ``xs:dateTime`` of the AMF (``YYYY-MM-DDTHH:MM:SSZ``).
    applied
        Whether the images the AMF goes with already have the transform applied.

    Returns
    -------
    str
        UTF-8 XML text. The UUIDs are name-based (RFC 4122 version 5) on the
        transform ID, the CLF's digest and ``applied``: the same transform
        gives the same AMF up to its time.

    Raises
    ------
    CamcalError
        A transform to another space than ACES2065-1, a digest that is not
        32 bytes or a malformed time.
    """
    if transform.space != "ACES2065-1":
        raise CamcalError(f"an AMF input transform converts to ACES2065-1, got one to {transform.space}")
    if len(clf_sha256) != 32:
        raise CamcalError(f"expected a 32-byte SHA-256 digest of the CLF, got {len(clf_sha256)} bytes")
    if not _DATE_TIME.fullmatch(created):
        raise CamcalError(f"expected an xs:dateTime such as 2026-01-31T12:00:00Z, got {created!r}")
    clf_file = quote(clf_path, safe="/")
    ET.register_namespace("aces", AMF_NAMESPACE)
    seed = f"{transform.transform_id}|{clf_sha256.hex()}|{applied}"
    root = ET.Element(f"{{{AMF_NAMESPACE}}}acesMetadataFile", {"version": AMF_VERSION})
    _info(root, "amfInfo", f"camcal: the ACES input transform of camera {transform.camera}", created,
          uuid.uuid5(uuid.NAMESPACE_URL, f"{seed}|amf"))
    pipeline = _element(root, "pipeline")
    info = _info(pipeline, "pipelineInfo", f"{transform.user_name}: camera code values to ACES2065-1", created,
                 uuid.uuid5(uuid.NAMESPACE_URL, f"{seed}|pipeline"))
    version = _element(info, "systemVersion")
    for name, value in zip(("majorVersion", "minorVersion", "patchVersion"), ACES_SYSTEM_VERSION):
        _element(version, name, str(value))
    step = _element(pipeline, "inputTransform", applied="true" if applied else "false")
    _element(step, "description", f"ACES transform ID {transform.transform_id} ({transform.user_name}), "
                                  f"CLF {clf_file}")
    _element(step, "hash", base64.b64encode(clf_sha256).decode("ascii"), algorithm=SHA256_ALGORITHM)
    _element(step, "file", clf_file)
    ET.indent(root, space="    ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
