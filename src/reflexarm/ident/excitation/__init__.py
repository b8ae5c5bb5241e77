"""Excitation trajectories (Sec. II-D): finite Fourier series, their optimization for a well-conditioned
regressor (:mod:`.design`), and their export as a sampled, checked trajectory (:mod:`.export`)."""
