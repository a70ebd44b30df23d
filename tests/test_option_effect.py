"""An option that does nothing for the chosen filters or sensors is one line and exit 2 (issue 30, minor):
``--alpha`` without a sigma-point filter, ``--tau`` without an adaptive filter, the DVL flags with
``dvl-beams``; the same domain for ``--filter-option ukf.alpha`` as for ``--alpha``; ``--n-boot 0``.
Explicit (command line or config) counts, even at the default value; an option left at its default is
never an error. The check is the library's (experiments.spec.check_effective): the API gets it too."""
from __future__ import annotations

import dataclasses

import pytest

from conftest import assert_one_error_line, nespm
from nespm_cli.errors import NespmError
from nespm_cli.experiments.spec import Spec, validate
from nespm_cli.filters import FilterConfig

pytestmark = pytest.mark.usefixtures("no_env_data_dir")


def mc(tmp_path, data, *extra):
    return nespm("mc", "--data-dir", str(data), "--tracks", "5", "--runs", "2", "--no-progress", "--jobs", "1",
                 *extra, "--out", str(tmp_path / "r"))


@pytest.mark.parametrize("extra, words", [
    (("--filters", "ekf", "--alpha", "0.5"), ("--alpha", "sigma-point", "ukf", "--filters (ekf)")),
    (("--filters", "ekf", "--alpha", "1"), ("--alpha", "--filters (ekf)")),  # explicit at the default value
    (("--filters", "ekf,ukf", "--tau", "0.5"), ("--tau", "adaptive", "anukf", "--filters (ekf,ukf)")),
    (("--filters", "ekf", "--q-clip", "0.5", "3"), ("--q-clip", "adaptive")),
    (("--filters", "ekf", "--state", "15", "--sensors", "dvl-beams", "--dvl-noise", "0.05"),
     ("--dvl-noise", "dvl sensor", "--sensors (dvl-beams)")),
    (("--filters", "ekf", "--state", "15", "--sensors", "dvl-beams", "--dvl-lever-arm", "1", "0", "0"),
     ("--dvl-lever-arm", "--sensors (dvl-beams)")),
    (("--filters", "ekf", "--outage-start", "100"), ("--outage-start", "--scenario outage")),
])
def test_option_without_effect_is_refused_before_anything_is_written(tmp_path, short_data_dir, extra, words):
    assert_one_error_line(*mc(tmp_path, short_data_dir, *extra), *words)
    assert not (tmp_path / "r").exists()


def test_option_from_a_config_file_counts_as_given(tmp_path, short_data_dir):
    cfg = tmp_path / "c.toml"
    cfg.write_text('filters = "ekf"\nalpha = 1.0\n', encoding="utf-8")
    assert_one_error_line(*mc(tmp_path, short_data_dir, "--config", str(cfg)), "--alpha", "--filters (ekf)")
    assert not (tmp_path / "r").exists()


def test_filter_option_alpha_has_the_domain_of_alpha(tmp_path, short_data_dir):
    a = assert_one_error_line(*mc(tmp_path, short_data_dir, "--filters", "ukf", "--alpha", "2"), "--alpha")
    b = assert_one_error_line(*mc(tmp_path, short_data_dir, "--filters", "ukf", "--filter-option", "ukf.alpha=2"),
                              "--filter-option ukf.alpha")
    assert a.split("--alpha")[1] == b.split("--filter-option ukf.alpha")[1]  # the same rule, word for word
    assert_one_error_line(*mc(tmp_path, short_data_dir, "--filters", "ukf", "--filter-option", "ukf.alpha=0"),
                          "0 < alpha <= 1")
    assert not (tmp_path / "r").exists()


def test_library_refuses_without_the_cli(short_data_dir):
    base = Spec(tracks=(5,), runs=2, data_dir=str(short_data_dir), filters=("ekf",))
    with pytest.raises(NespmError, match="--alpha"):
        validate(dataclasses.replace(base, filter_config=FilterConfig(alpha=0.5)))
    with pytest.raises(NespmError, match="--tau-a"):
        validate(dataclasses.replace(base, filter_config=FilterConfig(tau_a=2.0)))
    with pytest.raises(NespmError, match="--alpha"):  # given explicitly, even at the default
        validate(dataclasses.replace(base, given=("alpha",)))
    # where a filter uses it, or left at its default: accepted, and `given` is no part of the experiment
    ok = validate(dataclasses.replace(base, filters=("ekf", "ukf"), filter_config=FilterConfig(alpha=0.5),
                                      given=("alpha",)))
    assert ok.filter_config.alpha == 0.5 and "given" not in ok.as_dict()
    assert validate(base).as_dict() == validate(dataclasses.replace(base, given=("seed",))).as_dict()


@pytest.mark.parametrize("n", ["0", "-3"])
def test_n_boot_below_one_is_refused(tmp_path, n):
    assert_one_error_line(*nespm("report", str(tmp_path), "--n-boot", n), "--n-boot", "at least 1")
    assert_one_error_line(*nespm("compare", str(tmp_path), str(tmp_path), "--n-boot", n), "--n-boot", "at least 1")
