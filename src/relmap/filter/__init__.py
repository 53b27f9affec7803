"""The extended Kalman filter (lecture Eqs. 13-28) and the noise of a filter from its own
innovations (:mod:`.autocalibration`)."""
