"""Noise models as a plugin kind (docs/learned.md): what maps IMU windows to the process-noise
std the adaptive filters (anekf, anukf, anukf-nespm) turn into Q (eqs 43-48,
:mod:`nespm_cli.filters.adaptive`).

A noise model is a small object (:class:`NoiseModel`): a ``name``, the ``window`` length in IMU
steps, the IMU ``rate_hz`` it was made for, the ``source`` file, and
``predict(windows) -> std``: raw IMU windows ``(..., window, 6)`` (specific force x, y, z
[m/s²], then angular rate x, y, z [rad/s], one window per run and DVL interval, batched over
any leading axes) to the per-axis white-noise std ``(..., 6)`` in the same units per IMU sample,
unclipped (the filters clip it to ``--q-clip`` x the nominal std). A model that predicts Q scale
factors instead returns ``nominal · sqrt(scale)`` (see :class:`nespm_cli.learn.onnx_model.OnnxNoiseModel`).

Built in: ProcessNet (a ``.npz`` from ``nespm train``, :class:`ProcessNetModel`) and ONNX
(a ``.onnx`` run by onnxruntime, :mod:`nespm_cli.learn.onnx_model`). More kinds register by file
suffix, in code (:func:`register`) or through the ``nespm.noise_models`` entry point whose name
is the suffix (without the dot) and whose object is a ``load(path) -> NoiseModel``.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Callable

import numpy as np

from nespm_cli.errors import NespmError
from nespm_cli.learn.noise_model import (IMU_RATE_HZ, OPTION, NoiseModel, default_weights, interval_windows,
                                         load_weights, output_problem, reference_windows)

#: the entry-point group of noise-model plugins (name: file suffix without the dot)
ENTRY_POINT_GROUP = "nespm.noise_models"
__all__ = ["NoiseModel", "ProcessNetModel", "IMU_RATE_HZ", "register", "unregister", "loaders", "load_noise_model",
           "predict_interval_std", "export_processnet", "typed_option"]


class ProcessNetModel(NoiseModel):
    """The built-in: the accelerometer and gyro ProcessNets of a ``nespm train`` file (numpy)."""

    name = "processnet"

    def __init__(self, acc_net, gyro_net, source: Path | None = None):
        self.acc, self.gyro, self.source = acc_net, gyro_net, source
        self.window = int(acc_net.window)

    def predict(self, windows: np.ndarray) -> np.ndarray:
        from nespm_cli.learn.training import predict_noise_std

        x = np.asarray(windows, dtype=np.float64)
        a, g = predict_noise_std(self.acc, self.gyro, x[..., :3], x[..., 3:], clip=None)
        return np.concatenate([a, g], axis=-1)


def _load_processnet(path: Path) -> NoiseModel:
    acc, gyro, _ = load_weights(str(path))
    return ProcessNetModel(acc, gyro, path)


def _load_onnx(path: Path) -> NoiseModel:
    from nespm_cli.learn.onnx_model import OnnxNoiseModel

    return OnnxNoiseModel(path, reference=np.concatenate(reference_windows(), axis=-1))


_LOADERS: dict[str, Callable[[Path], NoiseModel]] = {"npz": _load_processnet, "onnx": _load_onnx}


def register(suffix: str, load: Callable[[Path], NoiseModel]) -> None:
    """Make ``--noise-model FILE.<suffix>`` load with ``load(path) -> NoiseModel``."""
    _LOADERS[suffix.lower().lstrip(".")] = load


def unregister(suffix: str) -> None:
    """Remove a kind :func:`register` added (the built-ins stay)."""
    key = suffix.lower().lstrip(".")
    if key not in ("npz", "onnx"):
        _LOADERS.pop(key, None)


def loaders() -> dict[str, Callable[[Path], NoiseModel]]:
    """Suffix -> loader: the built-ins, then the ``nespm.noise_models`` entry points (which may
    not replace a built-in)."""
    from importlib.metadata import entry_points

    out = dict(_LOADERS)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name.lower() not in out:
            out[ep.name.lower()] = ep  # loaded on use only
    return out


def typed_option(given=()) -> str:
    """The spelling of the model option to name in messages: ``--weights`` when only that alias was
    given (``given``: the option names of ``Spec.given``, ``"weights"``/``"noise_model"``), else
    ``--noise-model``; :data:`~nespm_cli.learn.noise_model.OPTION` (both) when ``given`` says neither."""
    names = {str(g).replace("-", "_") for g in given}
    if "noise_model" in names:
        return "--noise-model"
    return "--weights" if "weights" in names else OPTION


def load_noise_model(path: str | None, option: str | None = None) -> NoiseModel:
    """The noise model of ``--noise-model`` (alias ``--weights``) ``path``; None: the packaged
    ProcessNet. Cached per process; every failure is one NespmError naming the file and ``option``
    (the spelling the user typed, :func:`typed_option`; None: both spellings)."""
    try:
        return _load_noise_model(path)
    except NespmError as exc:
        msg = str(exc)
        if option and msg.startswith(OPTION):
            raise NespmError(option + msg[len(OPTION):]) from None
        raise


@lru_cache(maxsize=8)
def _load_noise_model(path: str | None) -> NoiseModel:
    p = Path(path).expanduser() if path else default_weights()
    what = f"{OPTION} {p}"
    kinds = loaders()
    suffix = p.suffix.lower().lstrip(".")
    if suffix not in kinds:
        raise NespmError(f"{what}: unknown model file type {p.suffix or '(none)'!r}; "
                         f"known: {', '.join('.' + k for k in sorted(kinds))} (docs/learned.md)")
    load = kinds[suffix]
    if not callable(load):  # an entry point
        try:
            load = load.load()
        except Exception as exc:
            raise NespmError(f"{what}: plugin {ENTRY_POINT_GROUP}:{suffix} cannot be loaded "
                             f"({type(exc).__name__}: {exc})") from None
    try:
        model = load(p)
    except NespmError:
        raise
    except Exception as exc:  # a plugin's loader that fails on this file
        raise NespmError(f"{what}: cannot be loaded as .{suffix} ({type(exc).__name__}: "
                         f"{str(exc).splitlines()[0][:200] if str(exc) else ''})") from None
    if not isinstance(model, NoiseModel):
        raise NespmError(f"{what}: the {suffix} loader returned {type(model).__name__}, not a NoiseModel")
    if abs(float(model.rate_hz) - IMU_RATE_HZ) > 1e-9:
        raise NespmError(f"{what}: made for a {model.rate_hz:g} Hz IMU; the experiments run at "
                         f"{IMU_RATE_HZ:g} Hz")
    if suffix not in ("npz", "onnx"):  # the built-ins check themselves, on the same windows
        check_plugin_model(model, what)
    return model


def check_plugin_model(model: NoiseModel, what: str) -> None:
    """A plugin's model run once on the reference windows (:func:`reference_windows`, their last
    ``model.window`` steps): ``(2, 20, 6)`` outputs, every one finite and > 0
    (:func:`~nespm_cli.learn.noise_model.output_problem`), else one NespmError starting with ``what``."""
    x = np.concatenate(reference_windows(), axis=-1)
    w = int(model.window)
    if not 0 < w <= x.shape[-2]:
        return  # windows longer than the reference's: checked by the filters at run time only
    try:
        with np.errstate(all="ignore"):
            y = np.asarray(model.predict(x[..., -w:, :]), dtype=float)
    except Exception as exc:
        raise NespmError(f"{what}: predict fails on {x.shape[0] * x.shape[1]} reference windows "
                         f"({type(exc).__name__}: {str(exc).splitlines()[0][:200] if str(exc) else ''})") from None
    if y.shape != x.shape[:2] + (6,):
        raise NespmError(f"{what}: predict returned shape {y.shape} on windows {x[..., -w:, :].shape}, expected "
                         f"{x.shape[:2] + (6,)}")
    bad = output_problem(y)
    if bad:
        raise NespmError(f"{what}: on the reference windows {bad}")


def predict_interval_std(f_meas: np.ndarray, w_meas: np.ndarray, epoch_index: np.ndarray,
                         weights: str | None = None, clip: tuple[float, float] | None = None):
    """Noise std of the noise model ``weights`` (``--noise-model``/``--weights``: a ProcessNet
    .npz, an .onnx or a plugin's file; None: the packaged ProcessNet) for every run and DVL
    interval, in one batched call.

    Args:
        f_meas, w_meas: (R, M, 3) IMU readings [m/s², rad/s]; epoch_index: (N,) IMU sample of each epoch.
        clip: None (the filters clip) or ``(lo, hi)`` multiples of the nominal std (an output that
            is non-finite or <= 0 becomes NaN, never a clip bound).

    Returns ``(std_a, std_g)``, each (R, N-1, 3) [m/s², rad/s per IMU sample], raw: a value that is
    non-finite or <= 0 is passed on as it is (the filters lose that run, docs/learned.md).
    """
    from nespm_cli.data.corruption import NOMINAL_ACC_NOISE, NOMINAL_GYRO_NOISE

    model = load_noise_model(weights)
    with np.errstate(all="ignore"):  # a model's non-finite or non-positive output is the filters' to count
        std = model.predict(np.concatenate([interval_windows(np.asarray(x, dtype=np.float64), epoch_index,
                                                             model.window) for x in (f_meas, w_meas)], axis=-1))
    a, g = np.asarray(std[..., :3], dtype=float), np.asarray(std[..., 3:], dtype=float)
    if clip is not None:  # a value that breaks the rule (non-finite or <= 0) stays NaN: never clipped into range
        with np.errstate(invalid="ignore"):
            a = np.where(np.isfinite(a) & (a > 0), np.clip(a, clip[0] * NOMINAL_ACC_NOISE, clip[1] * NOMINAL_ACC_NOISE),
                         np.nan)
            g = np.where(np.isfinite(g) & (g > 0),
                         np.clip(g, clip[0] * NOMINAL_GYRO_NOISE, clip[1] * NOMINAL_GYRO_NOISE), np.nan)
    return a, g


def export_processnet(weights, out) -> Path:
    """Write the ProcessNet of ``weights`` (a ``nespm train`` .npz; None: the packaged one) as
    ONNX to ``out`` (:func:`nespm_cli.learn.onnx_model.processnet_onnx`); returns ``out``."""
    from nespm_cli.learn.onnx_model import processnet_onnx

    acc, gyro, _ = load_weights(str(weights) if weights else None)
    model = processnet_onnx(acc, gyro, {"weights": Path(weights).name if weights else "packaged"})
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_bytes(model.SerializeToString())
    tmp.replace(out)
    return out
