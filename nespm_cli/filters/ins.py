"""``ins``: free inertial navigation — strapdown only, no covariance, no measurement update."""
from __future__ import annotations

from nespm_cli.filters.protocol import ErrorStateFilter
from nespm_cli.filters.registry import register


@register("ins")
class InsFilter(ErrorStateFilter):
    """Free inertial: ``propagate`` integrates the IMU; ``update`` is never called
    (``has_covariance`` False); ``check`` fails a run only on a non-finite solution."""

    has_covariance = False

    def propagate(self, j0: int, j1: int, k: int = 0) -> None:
        self.strapdown(j0, j1)

    def update(self, measurement, j_last: int) -> None:  # pragma: no cover - never called
        raise NotImplementedError("ins has no measurement update")
