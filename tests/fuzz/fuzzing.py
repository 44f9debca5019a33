"""Fuzzing profiles and the count of what ran: ``CAMCAL_FUZZ=long`` (``make fuzz``) or the quick default.

The quick profile (``make test``) is derandomised (the same examples every
run, no example database written); the long one draws new examples each run
and keeps Hypothesis' database of failures in ``.hypothesis/``.
"""

import os
from collections import Counter

from hypothesis import HealthCheck, settings

#: reader -> examples run in this session (filled by ``test_fuzz_readers.run_reader``).
EXAMPLES: Counter = Counter()

PROFILE = os.environ.get("CAMCAL_FUZZ", "quick").strip() or "quick"
_COMMON = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                     HealthCheck.filter_too_much])
settings.register_profile("camcal-fuzz-quick", max_examples=200, derandomize=True, database=None, **_COMMON)
settings.register_profile("camcal-fuzz-long", max_examples=int(os.environ.get("CAMCAL_FUZZ_EXAMPLES", "1500")),
                          **_COMMON)
if PROFILE not in ("quick", "long"):
    raise ValueError(f"CAMCAL_FUZZ must be quick or long, got {PROFILE!r}")
FUZZ = settings.get_profile(f"camcal-fuzz-{PROFILE}")

