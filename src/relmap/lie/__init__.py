"""Lie-group geometry (no covariance): one module per group, batched over leading axes."""

from relmap.lie import se2

__all__ = ["se2"]
