import re

import pytest

from modalctl.units import UnitError, parse_point, parse_quantity


@pytest.mark.parametrize("text, unit, expected", [
    ("18mm", "m", 0.018), ("18 mm", "m", 0.018), ("0.018", "m", 0.018), (0.018, "m", 0.018),
    ("25ms", "s", 0.025), ("1%", "1", 0.01), ("40mm/s", "m/s", 0.04), ("2kHz", "Hz", 2000.0),
    ("-46mm", "m", -0.046), ("1e-3m", "m", 0.001), ("150V", "V", 150.0), ("50um", "m", 5e-5),
])
def test_parses_to_si(text, unit, expected):
    assert parse_quantity(text, unit) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("text, unit", [("18kg", "m"), ("abc", "m"), ("18 m m", "m"), ("5ms", "m"), ("", "s")])
def test_bad_units_name_field_and_value(text, unit):
    with pytest.raises(UnitError) as info:
        parse_quantity(text, unit, name="width")
    assert "width" in str(info.value)


@pytest.mark.parametrize("unit, example", [("m", "18mm"), ("N s/m", "18N s/m"), ("1/s", "181/s"), ("Hz", "18Hz"),
                                           ("1", "18%")])
def test_an_unreadable_number_s_example_is_in_its_own_unit(unit, example):
    """Issue 39: --finger nan said "(example: 18mm)", a length, for a damping in N s/m."""
    with pytest.raises(UnitError, match=f"cannot read 'nan' .*\\(example: {re.escape(example)}\\)"):
        parse_quantity("nan", unit, name="finger")


def test_points():
    assert parse_point("24mm,-10mm", "m") == pytest.approx((0.024, -0.010))
    assert parse_point(0.01, "m") == (0.01,)
