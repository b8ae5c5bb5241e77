"""Default settings of a threshold study, in a module that imports nothing heavy (the command line
registers ``tune-thresholds`` with them without loading the study)."""

from __future__ import annotations

__all__ = ["DEFAULT_CONTACT_RATE", "DEFAULT_METHOD", "DEFAULT_RATE", "GAP_TIME_CONSTANTS"]

#: Declustering gap in the detector's time scale 1/k_o + 1/K_f (1/k_o without a second stage): excursions closer
#: than 5 x that (1 s at k_o = 5 1/s, where the observer's step response has settled to 99.3 %; a cascade's step
#: response is at least as settled at 5 x its sum of time constants) are one alarm, as a latched detector sees.
GAP_TIME_CONSTANTS = 5.0

#: Default false-alarm rate of the collision level for the whole arm [1/h].
DEFAULT_RATE = 1.0
#: Default rate of the contact level [1/h] (one a minute, as a lower libfranka-style level).
DEFAULT_CONTACT_RATE = 60.0
#: Default tail model: exponential (xi = 0). The residual's noise is a low-passed sum of many small bounded
#: contributions (sensor noise through M_hat(q), model errors along the motion), a tail in the Gumbel domain
#: (xi = 0); a shape fitted from the ~30 largest excursions comes out negative (-0.2 to -0.6 on the Atlas
#: free-motion logs) and puts a false end to the tail just above the logs' maximum: measured on a held-out
#: 10-minute run, such GPD levels were crossed on 1-2 joints, the exponential ones not (see the report of
#: issue 9). "gpd" stays available.
DEFAULT_METHOD = "exponential"
