import dataclasses
import math

import pytest

from mapserver.core import fusion_kernel
from mapserver.core.sensor_model import (
    POLICY_CODES,
    DecayParams,
    Policy,
    SensorModel,
    fill_legacy_sensor_model,
    logit,
    sigmoid,
)


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


# The three shapes of an old data dir's recorded sensor model, and what each read as
# before the legacy table moved beside the model (written out, not computed).
CORE = {
    "p_hit": 0.7, "p_miss": 0.4, "prior": 0.5, "clamp_min": -5.0, "clamp_max": 5.0,
    "occupied_threshold": 0.65, "free_threshold": 0.25,
}  # fmt: skip
BEFORE_NO_RETURN = CORE
BEFORE_CLEARING = {**CORE, "p_miss_no_return": 0.42, "no_return_range": 3.0}
BEFORE_DUAL = {**BEFORE_CLEARING, "fill_between_beams": True, "guard_glancing_faces": True}


@pytest.mark.parametrize(
    "recorded, filled",
    [
        (BEFORE_NO_RETURN, {
            **CORE, "p_miss_no_return": 0.4, "no_return_range": None,
            "fill_between_beams": False, "guard_glancing_faces": False,
            "void_threshold": 0.05, "confirm_hits": 10, "confirm_after": 2.0,
            "confirm_within": 60.0, "release_margin": 0.3, "transient_half_life": 5.0,
        }),
        (BEFORE_CLEARING, {
            **CORE, "p_miss_no_return": 0.42, "no_return_range": 3.0,
            "fill_between_beams": False, "guard_glancing_faces": False,
            "void_threshold": 0.05, "confirm_hits": 10, "confirm_after": 2.0,
            "confirm_within": 60.0, "release_margin": 0.3, "transient_half_life": 5.0,
        }),
        (BEFORE_DUAL, {
            **CORE, "p_miss_no_return": 0.42, "no_return_range": 3.0,
            "fill_between_beams": True, "guard_glancing_faces": True,
            "void_threshold": 0.05, "confirm_hits": 10, "confirm_after": 2.0,
            "confirm_within": 60.0, "release_margin": 0.3, "transient_half_life": 5.0,
        }),
        ({"p_hit": 0.8}, {  # no p_miss (no server wrote this): no no-return pair, as before
            "p_hit": 0.8, "fill_between_beams": False, "guard_glancing_faces": False,
            "void_threshold": 0.05, "confirm_hits": 10, "confirm_after": 2.0,
            "confirm_within": 60.0, "release_margin": 0.3, "transient_half_life": 5.0,
        }),
    ],
    ids=["before-no-return", "before-clearing", "before-dual", "no-p-miss"],
)  # fmt: skip
def test_an_old_record_is_filled_with_the_values_it_was_fused_under(recorded, filled):
    model = dict(recorded)
    assert fill_legacy_sensor_model(model) is model  # in place
    assert model == filled
    assert fill_legacy_sensor_model(dict(filled)) == filled  # a full record: unchanged
    if "p_miss" in filled:
        SensorModel(**model)  # a valid model


def test_a_record_of_today_needs_no_filling():
    today = dataclasses.asdict(SensorModel(no_return_range=None, confirm_hits=3))
    assert fill_legacy_sensor_model(dict(today)) == today


def test_the_kernel_codes_come_from_the_one_table():
    assert sorted(POLICY_CODES.values()) == list(range(len(Policy)))  # each policy its own
    assert {p: getattr(fusion_kernel, f"POLICY_{p.name}") for p in Policy} == POLICY_CODES


def test_the_kernel_model_holds_each_value_by_name():
    model = SensorModel(
        p_hit=0.8, p_miss=0.3, prior=0.45, clamp_min=-4, clamp_max=6, p_miss_no_return=0.35,
        void_threshold=0.1, confirm_hits=7, confirm_after=3, confirm_within=12,
        transient_half_life=4,
    )  # fmt: skip
    decay = DecayParams(half_life_occupied=20, half_life_free=90)
    record = fusion_kernel.kernel_model(model, decay, Policy.DUAL)
    assert record._asdict() == {
        "l_hit": model.l_hit,
        "l_miss": model.l_miss,
        "l_miss_no_return": model.l_miss_no_return,
        "l0": model.l0,
        "clamp_min": -4.0,
        "clamp_max": 6.0,
        "policy": fusion_kernel.POLICY_DUAL,
        "half_life_occupied": 4.0,  # under dual, the transient half life
        "half_life_free": 90.0,
        "l_void": model.l_void,
        "confirm_hits": 7,
        "confirm_after": 3.0,
        "confirm_within": 12.0,
    }
    assert fusion_kernel.kernel_model(model, decay, Policy.DECAY).half_life_occupied == 20.0
    # Typed as the kernels are compiled for (an int would be another signature).
    assert [type(v) for v in record] == [
        int if name in ("policy", "confirm_hits") else float for name in record._fields
    ]
