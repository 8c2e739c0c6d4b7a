"""FilterConfig: defaults, validation naming the setting at fault, TOML loading."""

import numpy as np
import pytest

from ekf.config import FilterConfig
from ekf.errors import InputError


def test_defaults_are_valid_and_matrices_full_rank():
    cfg = FilterConfig()
    assert np.linalg.matrix_rank(cfg.pixel_cov) == 4
    assert cfg.velocity_cov.shape == (6, 6)
    assert np.all(np.linalg.eigvalsh(cfg.initial_pose_cov) > 0)


@pytest.mark.parametrize(
    "change, key",
    [
        ({"pixel_sigma": 0.0}, "pixel_sigma"),
        ({"velocity_sigma": -1.0}, "velocity_sigma"),
        ({"gate_probability": 1.5}, "gate_probability"),
        ({"velocity_pairing": "sideways"}, "velocity_pairing"),
        ({"min_disparity": -2.0}, "min_disparity"),
        ({"max_depth": float("nan")}, "max_depth"),
    ],
)
def test_bad_values_name_the_setting(change, key):
    with pytest.raises(InputError, match=key):
        FilterConfig().replace(**change)


def test_unknown_setting_is_named():
    with pytest.raises(InputError, match="pixel_sigmaa"):
        FilterConfig().replace(pixel_sigmaa=1.0)


def test_toml(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('[filter]\npixel_sigma = 2.0\nvelocity_pairing = "next"\n')
    cfg = FilterConfig.from_toml(p)
    assert cfg.pixel_sigma == 2.0 and cfg.velocity_pairing == "next"
    p.write_text("pixel_sigma = 2.0\nbogus = 1\n")
    with pytest.raises(InputError, match=r"s\.toml.*bogus"):
        FilterConfig.from_toml(p)
    p.write_text("pixel_sigma = = 2\n")
    with pytest.raises(InputError, match="not valid TOML"):
        FilterConfig.from_toml(p)
    with pytest.raises(InputError, match="not found"):
        FilterConfig.from_toml(tmp_path / "missing.toml")


def test_toml_leaves_the_smoother_table_to_the_smoother(tmp_path):
    from graph.settings import SmootherSettings

    p = tmp_path / "s.toml"
    p.write_text('pixel_sigma = 2.0\n[smoother]\ninit = "isam2"\n')
    assert FilterConfig.from_toml(p).pixel_sigma == 2.0
    p.write_text('[filter]\npixel_sigma = 2.0\n[smoother]\ninit = "isam2"\nhuber_k = 2\n')
    assert FilterConfig.from_toml(p).pixel_sigma == 2.0
    s = SmootherSettings.from_mapping({"init": "isam2", "huber_k": 2}, "s.toml [smoother]")
    assert s.init == "isam2" and s.huber_k == 2.0
    with pytest.raises(InputError, match=r"s\.toml \[smoother\].*'gap_twist_prior'"):
        SmootherSettings.from_mapping({"gap_twist_prior": True}, "s.toml [smoother]")
