"""The time written in camcal files' provenance (the one thing a re-run changes in them)."""

from __future__ import annotations

import datetime as _dt

__all__ = ["utc_timestamp"]


def utc_timestamp() -> str:
    """The current UTC time as written in camcal files' provenance: ``YYYY-MM-DDTHH:MM:SSZ``."""
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
