"""``json_text.loads``: orjson, and Python's ``json`` reading as orjson does for what
orjson refuses, give one reading of any JSON text ``json.dumps`` writes."""

import json
import math

import orjson
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapserver.json_text import TooDeep, loads, read_fallback

# JSON values as Python's json module writes them: NaN and infinities, integers wider than
# 64 bits, any text (lone surrogates too, escaped as \uXXXX by json.dumps).
JSON_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**80), max_value=2**80)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4)
    ),
    max_leaves=12,
)


def same_json(a, b) -> bool:
    """Equal as JSON values, NaN equal to NaN, and of the same Python types."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, list):
        return len(a) == len(b) and all(map(same_json, a, b))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same_json(a[k], b[k]) for k in a)
    return a == b


@settings(max_examples=300, deadline=None)
@given(value=JSON_VALUES, ensure_ascii=st.booleans())
def test_loads_reads_every_text_as_the_fallback_reads_it(value, ensure_ascii):
    """Whichever reader takes a text, the value is the fallback's; a lone surrogate
    written raw is not UTF-8 and both refuse it."""
    raw = json.dumps(value, ensure_ascii=ensure_ascii).encode("utf-8", "surrogatepass")
    try:
        expected = read_fallback(raw)
    except ValueError:
        with pytest.raises(ValueError):
            loads(raw)
        return
    assert same_json(loads(raw), expected)


@pytest.mark.parametrize(
    ("raw", "expected"),
    [
        (b'{"stamp": NaN}', {"stamp": math.nan}),
        (b'{"max": Infinity, "min": -Infinity}', {"max": math.inf, "min": -math.inf}),
        (b'{"unit_id": "\\ud800"}', {"unit_id": "\ud800"}),
        (b'{"x": NaN, "n": 123456789012345678901}', {"x": math.nan, "n": 1.2345678901234568e20}),
    ],
)
def test_what_orjson_refuses_is_read_by_the_fallback(raw, expected):
    with pytest.raises(orjson.JSONDecodeError):
        orjson.loads(raw)
    assert same_json(loads(raw), expected)


def test_an_integer_wider_than_64_bits_is_the_nearest_float_from_either_reader():
    assert same_json(loads(b"[123456789012345678901]"), [1.2345678901234568e20])
    assert same_json(loads(b"[NaN, 123456789012345678901]"), [math.nan, 1.2345678901234568e20])


@pytest.mark.parametrize(
    "raw", [b"", b"{", b"\xff\xfe{}", b'{"a": 1} x', b"\xef\xbb\xbf{}", b"[1" + b"0" * 400 + b"]"]
)
def test_a_text_neither_reader_takes_is_a_value_error(raw):
    with pytest.raises(ValueError):
        loads(raw)


def test_a_text_nested_past_orjsons_limit_is_too_deep():
    with pytest.raises(TooDeep):
        loads(b"[" * 2000 + b"]" * 2000)


def test_a_text_nested_past_pythons_stack_is_too_deep():
    """orjson refuses the NaN; Python's ``json`` then runs out of stack on 1,010 levels
    (3.11) or reads them (3.12's C stack goes deeper): TooDeep, or the fallback's value."""
    raw = b"[" * 1010 + b"NaN" + b"]" * 1010
    try:
        read_fallback(raw)
    except RecursionError:
        with pytest.raises(TooDeep):
            loads(raw)
        return
    value = loads(raw)
    for _ in range(1010):  # unwrapped level by level: comparing would recurse as deep
        (value,) = value
    assert math.isnan(value)
