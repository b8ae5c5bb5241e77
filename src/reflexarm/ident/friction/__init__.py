"""Single-joint friction (Sec. II-D, eqs. (14)-(15)): constant-velocity runs, their segmentation and the
Coulomb + viscous fit, and the friction parameters with their plausibility checks."""
