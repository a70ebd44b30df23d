"""``anekf``, ``anukf``, ``anukf-nespm``: the EKF, UKF and UKF-NESPM with Q from the ProcessNet
noise std of each DVL interval's IMU window (anukf.md eqs 43-49).

The same propagation and update as their non-adaptive twins (``adaptive_of``); only the
process noise differs: :meth:`ErrorStateFilter.process_noise` uses
:func:`nespm_cli.filters.adaptive.adaptive_q` whenever the filter holds a ``noise_std``,
which these filters require (``needs_noise_std``).

A learned model cannot fail quietly: a window whose output is non-finite or <= 0 on any axis
(:func:`nespm_cli.filters.adaptive.model_faults`) loses its run from the epoch that closes it,
with the reason ``noise-model`` (:func:`nespm_cli.filters.engine.run_filter`, for every filter that
``needs_noise_std``, a plugin's included; docs/learned.md "When a model fails at run time").
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
