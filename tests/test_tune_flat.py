"""``nespm tune --flat``: a parameter the objective cannot see goes back to its default where the training
score allows it (nespm_cli/tuning/flat.py; docs/tuning.md, "Flat parameters")."""
from __future__ import annotations

import pytest

from nespm_cli.errors import NespmError
from nespm_cli.tuning.flat import apply_flat_rule, flat_keys, reset_flat
from nespm_cli.tuning.profile import FLAT
from nespm_cli.tuning.run import run_tune
from nespm_cli.tuning.space import Param
from nespm_cli.tuning.spec import TuneSpec, check

from test_tune_recovery import RANGES, mis_set_world

SPACE = [Param("ekf", "a", 0.01, 100.0), Param("ekf", "b", 0.01, 100.0), Param("ekf", "c", 0.01, 100.0)]


def score(v: dict) -> float:
    """Seen in ``a`` (best at 2), blind to ``b``, and blind to ``c`` near its searched 50 but not at its
    default 1 (the score rises by 10 % there): a parameter flat at the profile's steps need not be flat
    all the way to its default."""
    return 1.0 + (v["a"] - 2.0) ** 2 + (0.1 if v["c"] < 10.0 else 0.0)


def profile_of(shape: dict) -> dict:
    return {"a": {"change": 4.0, "flat": False}, "b": {"change": 0.0, "flat": True},
            "c": {"change": 0.001, "flat": True}}


def test_reset_flat_keeps_what_the_score_sees():
    shape = {"a": 2.0, "b": 7.0, "c": 50.0}
    calls = []

    def ev(v):
        calls.append(dict(v))
        return score(v)

    got = reset_flat(shape, score(shape), profile_of(shape), SPACE, ev)
    assert got["reset"] == ["b"]
    assert got["shape"] == {"a": 2.0, "b": 1.0, "c": 50.0}
    assert got["kept"] == {"c": pytest.approx(1.1)}
    assert got["score"] == pytest.approx(1.0)
    assert flat_keys(profile_of(shape)) == ["b", "c"]  # smallest profile change first
    assert len(calls) == 2  # one evaluation per flat key whose value is not its default


def test_reset_tolerance_is_the_profiles():
    shape = {"a": 2.0, "b": 7.0, "c": 50.0}
    inside = reset_flat(shape, 1.0, profile_of(shape), SPACE, lambda v: 1.0 + 0.99 * FLAT * (v["b"] == 1.0))
    outside = reset_flat(shape, 1.0, profile_of(shape), SPACE, lambda v: 1.0 + 1.01 * FLAT * (v["b"] == 1.0))
    assert "b" in inside["reset"] and "b" not in outside["reset"]


def test_searched_rule_and_no_profile_change_nothing():
    b = {"shape": {"a": 2.0, "b": 7.0, "c": 50.0}, "values": {"a": 2.0, "b": 7.0, "c": 50.0}, "score": 1.0,
         "profile": profile_of({})}
    assert not apply_flat_rule(b, "searched", SPACE, score) and b["shape"]["b"] == 7.0
    assert b["flat"]["rule"] == "searched"
    nop = {"shape": {"a": 2.0, "b": 7.0, "c": 50.0}, "values": {"a": 2.0, "b": 7.0, "c": 50.0}, "score": 1.0}
    assert not apply_flat_rule(nop, "default", SPACE, score) and nop["flat"]["rule"] == "none (no profile)"
    assert apply_flat_rule(b | {"flat": None}, "default", SPACE, score)


def test_bad_flat_rule_is_one_line():
    with pytest.raises(NespmError, match="--flat: choose default or searched"):
        check(TuneSpec(mis_set_world(tracks=(5,), runs=2), trials=1, flat="prior"))


def test_innovation_tuning_resets_the_gyro_it_cannot_see(tmp_path):
    """The recovery world (tests/test_tune_innovation.py): over 90 s the innovations do not see the gyro
    white noise (profile change < 1e-3), so its tuned value goes back to the default 1 and tuned.toml
    writes 1.0; the acc and DVL factors the score sees stay searched. With ``--flat searched`` the gyro
    keeps the searched value."""
    spec = mis_set_world(tracks=(5,), runs=6)
    rec = run_tune(TuneSpec(spec, trials=12, objective="innovation", ranges=RANGES, refine_trials=0), tmp_path / "d")
    b = rec["best"]["ekf"]
    assert rec["flat"] == "default"
    assert "gyro_noise_scale" in b["flat"]["reset"], b["flat"]
    assert b["values"]["gyro_noise_scale"] == 1.0
    assert b["searched_shape"]["gyro_noise_scale"] == b["flat"]["searched"]["gyro_noise_scale"] != 1.0
    assert "r_scale_dvl" not in b["flat"]["reset"]
    assert b["flat"]["score"] <= b["score"] * (1 + FLAT)
    assert "gyro_noise_scale = 1.0" in (tmp_path / "d" / "tuned.toml").read_text()
    kept = run_tune(TuneSpec(spec, trials=12, objective="innovation", ranges=RANGES, refine_trials=0,
                             flat="searched"), tmp_path / "s")["best"]["ekf"]
    assert kept["values"]["gyro_noise_scale"] == b["flat"]["searched"]["gyro_noise_scale"]
    assert kept["flat"] == {"rule": "searched", "reset": [], "kept": {}}
