"""``anekf``, ``anukf``, ``anukf-nespm``: the EKF, UKF and UKF-NESPM with Q from the ProcessNet
noise std of each DVL interval's IMU window (anukf.md eqs 43-49).

The same propagation and update as their non-adaptive twins (``adaptive_of``); only the
process noise differs: :meth:`ErrorStateFilter.process_noise` uses
:func:`nespm_cli.filters.adaptive.adaptive_q` whenever the filter holds a ``noise_std``,
which these filters require (``needs_noise_std``).
"""
from __future__ import annotations

from nespm_cli.filters.ekf import EKF
from nespm_cli.filters.registry import register
from nespm_cli.filters.ukf import UKF, UKFNespm


@register("anekf")
class AdaptiveEKF(EKF):
    needs_noise_std = True
    adaptive_of = "ekf"


@register("anukf")
class AdaptiveUKF(UKF):
    needs_noise_std = True
    adaptive_of = "ukf"


@register("anukf-nespm")
class AdaptiveUKFNespm(UKFNespm):
    needs_noise_std = True
    adaptive_of = "ukf-nespm"
