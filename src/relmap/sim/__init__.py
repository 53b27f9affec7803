"""Simulation: Monte Carlo checks of any estimate (:mod:`.montecarlo`, the paper's §6.3), sweeps
(:mod:`.study`), here or on a Dask cluster (:mod:`.distributed`)."""
