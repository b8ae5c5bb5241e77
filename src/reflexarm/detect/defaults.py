"""Default settings of ``reflexarm detect``, in a module that imports nothing heavy (the command line registers
its options with them without loading the detector)."""

from __future__ import annotations

__all__ = ["DEFAULT_DETECTION_GAIN", "DETECTION_LAG_TARGET_S", "SHORTEST_IMPACT_S"]

#: The shortest impact the detector is meant to see [s]: hits during motion last 1-3 samples at 100 Hz on real
#: arms (10-30 ms, issue 17).
SHORTEST_IMPACT_S = 0.010

#: k_o of the detection observer [1/s] when neither the thresholds file nor the command line gives one: its time
#: constant is the shortest impact (1 / 0.010 s), so a rectangular 10 ms pulse reaches 63 % of its size in the
#: residual. At 100 Hz k_o dt = 1: only the exact discretization is stable there (the Euler one needs k_o dt < 1/2
#: with the period band). Chosen from that rule before any log was replayed, not tuned on the pulse logs.
DEFAULT_DETECTION_GAIN = 100.0

#: Issue 15's target: detection at most this long after the true external torque exceeds the level [s] (the
#: detection study's and the tuned pairs' choice).
DETECTION_LAG_TARGET_S = 0.010
