import pytest

from sb3_ef.common.schedules import get_step_schedule, linear_schedule


def test_linear_string_schedule():
    schedule = get_step_schedule("linear(1.0, 0.1, 100)")
    assert schedule(0) == pytest.approx(1.0)
    assert schedule(50) == pytest.approx(0.55)
    assert schedule(100) == pytest.approx(0.1)
    assert schedule(10_000) == pytest.approx(0.1)


def test_constants_and_callables():
    assert get_step_schedule(0.2)(123) == 0.2
    assert get_step_schedule("0.3")(5) == 0.3
    assert get_step_schedule(lambda step: step * 2.0)(4) == 8.0


@pytest.mark.parametrize("spec", ["linear(1.0, 0.1)", "cosine(1,0,10)", None, [1.0]])
def test_bad_specs_name_the_expected_form(spec):
    with pytest.raises(ValueError, match="linear\\(initial, final, duration\\)"):
        get_step_schedule(spec)


def test_linear_schedule_rejects_empty_duration():
    with pytest.raises(ValueError, match="positive"):
        linear_schedule(1.0, 0.0, 0)
