"""Lie-group geometry (no covariance): one module per group, batched over leading axes.

:mod:`~relmap.lie.group` describes each group as a value (:data:`SE2`, :data:`SE3`) for code that
serves both.
"""

from relmap.lie import se2, se3, so3
from relmap.lie.group import SE2, SE3, Group

__all__ = ["SE2", "SE3", "Group", "se2", "se3", "so3"]
