"""The effect catalogue: every MODEL.md name, its unit, and how it folds into the plant."""

import pytest

from pipeline.config import default_config
from pipeline.errors import ConfigError
from pipeline.model.effects import make_effect, parameter_names

@pytest.mark.parametrize("name, value, field, expected", [
    ("viscous_friction", 7.7e-4, "b", 7.7e-4 + 7.7e-4),          # adds to the model's b
    ("rack_inertia", 1.94e-3, "J", 4.857e-4 + 1.94e-3),
    ("spring_stiffness", 0.5, "K1", 0.5 * 0.8682),
])
def test_linear_effects_change_parameters(name, value, field, expected):
    base = default_config()
    spec = base.plant_spec((make_effect(name, {parameter_names(name)[0]: value}),))
    assert getattr(spec.params, field) == pytest.approx(expected)
    assert spec.is_linear


@pytest.mark.parametrize("name, value, attr", [
    ("coulomb_friction", 6e-4, "Tc"), ("backlash", 0.05, "gap"),
    ("loop_delay", 0.05, "Td"), ("current_sensor_offset", -0.06, "I0"),
])
def test_non_smooth_and_output_effects_set_their_term(name, value, attr):
    spec = default_config().plant_spec((make_effect(name, {parameter_names(name)[0]: value}),))
    assert getattr(spec, attr) == pytest.approx(value)


def test_driver_drop_never_reverses_the_voltage():
    spec = default_config().plant_spec((make_effect("driver_voltage_drop", {"Vd": 6.0}),))
    assert spec.v_drive == 0.0


def test_stacked_effects_of_one_kind_add_up():
    effects = (make_effect("loop_delay", {"Td": 0.02}), make_effect("loop_delay", {"Td": 0.03}))
    assert default_config().plant_spec(effects).Td == pytest.approx(0.05)


def test_out_of_bounds_and_wrong_types_are_refused():
    with pytest.raises(ConfigError, match="effects.backlash.gap"):
        make_effect("backlash", {"gap": 3.0})
    with pytest.raises(ConfigError, match="expected a number"):
        make_effect("backlash", {"gap": "wide"})
    with pytest.raises(ConfigError, match="missing parameter 'Tc'"):
        make_effect("coulomb_friction", {})
