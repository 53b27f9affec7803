"""Uncertain quantities: N-d Gaussians (:mod:`.gaussian`), their propagation through functions
(:mod:`.propagate`), integrals over them (:mod:`.quadrature`), and uncertain poses — the AT in
SE(2) (:mod:`.at`) and SE(3) (:mod:`.at3`) on one base (:mod:`.pose`), their exact moments
(:mod:`.moments`) and time series of them (:mod:`.trajectory`)."""
