import math

import pytest

from mapserver.core.sensor_model import DecayParams, Policy, SensorModel, logit, sigmoid


def test_defaults_are_the_contract_values_in_log_odds():
    m = SensorModel()
    assert (m.p_hit, m.p_miss, m.clamp_min, m.clamp_max) == (0.7, 0.4, -5.0, 5.0)
    assert (m.occupied_threshold, m.free_threshold) == (0.65, 0.25)
    assert m.l_hit == pytest.approx(0.8473, abs=1e-4)
    assert m.l_miss == pytest.approx(-0.4055, abs=1e-4)
    assert m.l0 == 0.0
    assert (m.p_miss_no_return, m.no_return_range) == (0.45, 1.0)
    assert m.l_miss_no_return == pytest.approx(math.log(0.45 / 0.55))  # -0.2007
    assert m.no_return_cap == 1.0
    assert SensorModel(no_return_range=None).no_return_cap == math.inf


def test_logit_and_sigmoid_are_inverse():
    for p in (0.01, 0.25, 0.5, 0.7, 0.99):
        assert sigmoid(logit(p)) == pytest.approx(p)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"p_hit": 0.5}, "p_hit must be greater than the prior"),
        ({"p_hit": 1.0}, "p_hit must be a probability"),
        ({"p_miss": 0.5}, "p_miss must be less than the prior"),
        ({"p_miss": 0.0}, "p_miss must be a probability"),
        ({"clamp_min": 0.0}, "clamp_min must be below"),
        ({"clamp_max": -1.0}, "clamp_max must be above"),
        ({"clamp_max": math.inf}, "clamp_max must be a finite"),
        ({"free_threshold": 0.7}, "free_threshold must be below the prior"),
        ({"occupied_threshold": 0.45}, "occupied_threshold must be above the prior"),
        ({"prior": 0.8}, "p_hit must be greater than the prior"),
        ({"p_miss_no_return": 0.55}, "p_miss_no_return must be between p_miss"),
        ({"p_miss_no_return": 0.3}, "p_miss_no_return must be between p_miss"),
        ({"p_miss_no_return": 0.0}, "p_miss_no_return must be a probability"),
        ({"no_return_range": 0.0}, "no_return_range must be a positive range"),
        ({"no_return_range": math.nan}, "no_return_range must be a positive range"),
    ],
)
def test_invalid_sensor_model_is_rejected_with_the_field_and_value(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SensorModel(**kwargs)


def test_invalid_decay_parameters_are_rejected():
    with pytest.raises(ValueError, match="half_life_free"):
        DecayParams(half_life_free=0.0)
    with pytest.raises(ValueError, match="fade_bound"):
        DecayParams(fade_bound=-1.0)


def test_policy_names_the_choices_on_a_bad_value():
    assert Policy.parse("sticky") is Policy.STICKY
    with pytest.raises(ValueError, match="decay, binary, sticky.*'fast'"):
        Policy.parse("fast")
