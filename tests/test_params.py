import math

import numpy as np
import pytest

from rollbot_oc.model.params import PARAM_VECTOR_FIELDS, RollbotParams, load_params, save_params


def test_defaults_are_the_paper_prototype():
    p = RollbotParams()
    assert (p.R, p.M_s, p.m_b, p.I, p.r0, p.m, p.g) == (0.12, 0.840, 0.040, 0.0053, 0.093, 0.306, 9.81)
    assert p.phi == pytest.approx(math.radians(45))
    assert p.M == pytest.approx(0.880)
    assert p.k0 == pytest.approx(0.4 * 0.880 * 0.12**2)
    assert p.max_torque == pytest.approx(0.28, abs=0.005)  # M_max = r0 m g
    assert p.max_speed == pytest.approx(3 * math.pi)
    assert p.slope == 0.0
    assert p.vector().shape == (len(PARAM_VECTOR_FIELDS),)


def test_k0_default_follows_mass_and_radius():
    p = RollbotParams(R=0.2, M_s=1.0)
    assert p.k0 == pytest.approx(0.4 * 1.04 * 0.04)


def test_toml_round_trip(tmp_path):
    p = RollbotParams(phi=math.radians(30), slope=math.radians(1), slope_dir=0.5, mu=0.8)
    path = tmp_path / "p.toml"
    save_params(p, path)
    q = load_params(path)
    assert np.allclose(p.vector(), q.vector(), rtol=1e-15, atol=0)


def test_partial_file_overrides_defaults(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text("phi_deg = 30\nslope_deg = 1.0\n")
    p = load_params(path)
    assert p.phi == pytest.approx(math.radians(30))
    assert p.slope == pytest.approx(math.radians(1))
    assert p.R == 0.12


@pytest.mark.parametrize("changes, field", [
    (dict(R=0.0), "R"), (dict(M_s=-1.0), "M_s"), (dict(I=float("nan")), "I"), (dict(m=float("inf")), "m"),
    (dict(phi=0.0), "phi"), (dict(phi=math.pi / 2), "phi"), (dict(r0=0.12), "r0"), (dict(r0=0.2), "r0"),
    (dict(mu=-0.1), "mu"), (dict(k0=-1e-3), "k0"), (dict(max_speed=0.0), "max_speed"),
    (dict(slope=math.radians(40)), "slope"), (dict(m_b=-0.01), "m_b"), (dict(g="9.81"), "g"),
    (dict(max_torque=True), "max_torque"),
])
def test_bad_values_name_the_field(changes, field):
    with pytest.raises(ValueError, match=field):
        RollbotParams(**changes)


def test_error_gives_value_and_range():
    with pytest.raises(ValueError) as info:
        RollbotParams(phi=math.radians(95))
    text = str(info.value)
    assert "phi" in text and "1.65" in text and "(0, 90)" in text


def test_unknown_key_in_file(tmp_path):
    path = tmp_path / "p.toml"
    path.write_text("R = 0.12\nradius = 3\n")
    with pytest.raises(ValueError, match="unknown key.*radius"):
        load_params(path)


def test_bad_files(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        load_params(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("R = = 1")
    with pytest.raises(ValueError, match="not valid TOML"):
        load_params(bad)
    text = tmp_path / "text.toml"
    text.write_text('R = "big"')
    with pytest.raises(ValueError, match="R.*must be a finite number"):
        load_params(text)
