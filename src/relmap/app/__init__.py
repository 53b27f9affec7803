"""The ``relmap`` command and the applications it runs: the demo and its report, EKF
localization on datasets, Monte Carlo validation of a query, trajectory commands."""
