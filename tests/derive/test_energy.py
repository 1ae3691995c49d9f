"""Energy terms: the paper's figure on the paper's simulation, and a balance that closes."""

import numpy as np
import pytest

from pipeline.config import default_config
from pipeline.derive.energy import ENERGY_KEYS, dead_zone, energy_terms, paper_energy_j
from pipeline.model.simulate import simulate


@pytest.fixture(scope="module")
def paper_run():
    spec = default_config().plant_spec()          # Table I with b = 7.7e-4, sampled guard, 500 samples
    return spec, simulate(spec)


def test_paper_energy_within_3_percent_of_16_496(paper_run):
    spec, r = paper_run
    e = energy_terms(r.t, r.current, r.omega, r.theta, r.u, spec, v_rms=6.0, period_s=0.05)
    assert len(r.t) == 500
    assert e["energy_paper_j"] == pytest.approx(16.496, rel=0.03)


def test_balance_closes_with_a_constant_load_torque():
    """The work done against a constant load torque (tau * delta theta) is booked, so the books still close."""
    from pipeline.model.effects import make_effect

    from pipeline.model.simulate import sample_times

    spec = default_config().plant_spec((make_effect("constant_load_torque", {"Tl": 3e-3}),))
    r = simulate(spec, sample_times(7.3, 0.001))      # 1 ms samples: trapezoids far finer than the load's work
    e = energy_terms(r.t, r.current, r.omega, r.theta, r.u, spec, v_rms=6.0, period_s=0.001)
    assert e["load_work_j"] == pytest.approx(3e-3 * (r.theta[-1] - r.theta[0]))
    assert abs(e["load_work_j"]) > 1e-3
    assert abs(e["balance_residual_j"]) < 0.05 * abs(e["load_work_j"])


def test_balance_closes_on_simulation(paper_run):
    spec, r = paper_run
    e = energy_terms(r.t, r.current, r.omega, r.theta, r.u, spec, v_rms=6.0, period_s=0.05)
    assert set(e) == set(ENERGY_KEYS)
    assert e["input_energy_j"] > 0 and e["copper_loss_j"] > 0 and e["friction_loss_j"] > 0
    # trapezoids at 50 ms: the books close to well under 1 % of the input energy
    assert abs(e["balance_residual_j"]) < 0.01 * e["input_energy_j"]


def test_paper_formula_by_hand():
    y = np.array([0.0, 1.0, -1.0, 2.0])
    # |0+1|/2 + |1-1|/2 + |-1+2|/2 = 1.0 -> 6 V * 0.05 s * 1.0
    assert paper_energy_j(y, 6.0, 0.05) == pytest.approx(0.3)
    assert np.isnan(paper_energy_j(y[:1], 6.0, 0.05))            # no interval: undefined, not 0


def test_dead_zone_and_backlash_spring():
    th = np.array([-0.3, -0.05, 0.0, 0.05, 0.3])
    assert np.allclose(dead_zone(th, 0.2), [-0.2, 0.0, 0.0, 0.0, 0.2])
    assert np.array_equal(dead_zone(th, 0.0), th)


def test_two_samples_and_one_sample_do_not_crash(paper_run):
    spec, _ = paper_run
    one = energy_terms(np.array([0.0]), np.array([0.1]), np.array([0.0]), np.array([0.0]),
                       np.array([6.0]), spec, 6.0, 0.05)
    assert all(np.isnan(v) for v in one.values())                # nothing to integrate: undefined, not 0
    two = energy_terms(np.array([0.0, 0.05]), np.array([0.0, 0.1]), np.zeros(2), np.zeros(2),
                       np.array([6.0, 6.0]), spec, 6.0, 0.05)
    assert two["input_energy_j"] == pytest.approx(6.0 * 0.05 * 0.05)
    with pytest.raises(ValueError):
        energy_terms(np.zeros(3), np.zeros(2), np.zeros(3), np.zeros(3), np.zeros(3), spec, 6.0, 0.05)


def test_applied_voltage_with_a_loop_delay():
    from pipeline.derive.energy import applied_voltage

    t = np.array([0.0, 0.05, 0.10, 0.15, 0.20])
    dirs = np.array([1, 1, -1, -1, -1])
    assert np.array_equal(applied_voltage(t, dirs, 6.0), dirs * 6.0)
    # 20 ms late: the first interval is 20 ms off then +6 V; the reversal at 0.10 s lands at 0.12 s
    u = applied_voltage(t, dirs, 6.0, Td=0.02)
    assert np.allclose(u[:4], [6.0 * 0.6, 6.0, 6.0 * (0.4 - 0.6), -6.0])


def test_balance_closes_with_a_loop_delay():
    from pipeline.derive.energy import applied_voltage
    from pipeline.model.effects import make_effect

    spec = make_effect("loop_delay", {"Td": 0.02}).apply(default_config().plant_spec())
    t = np.arange(0.0, 10.0, 0.05)
    r = simulate(spec, t)
    u = applied_voltage(r.t, r.dir, spec.v_drive, spec.Td)
    e = energy_terms(r.t, r.current, r.omega, r.theta, u, spec, 6.0, 0.05)
    assert abs(e["balance_residual_j"]) < 0.01 * e["input_energy_j"]


def test_run_energy_uses_the_supply_for_v_rms_and_the_delayed_command():
    """With a driver drop the paper's estimate still uses the supply's V_RMS; a loop delay shifts u."""
    import numpy as np

    from pipeline.config import default_config
    from pipeline.derive.energy import applied_voltage, energy_terms, run_energy
    from pipeline.model.effects import make_effect

    spec = default_config().plant_spec((make_effect("driver_voltage_drop", {"Vd": 1.0}),
                                        make_effect("loop_delay", {"Td": 0.02})))
    assert spec.v_drive == 5.0 and spec.v_rms == 6.0
    t = np.arange(40) * 0.05
    dirs = np.where(t < 1.0, 1, -1).astype(np.int8)
    current = np.sin(t)
    omega, theta = np.cos(t), np.sin(t)
    got = run_energy(t, current, omega, theta, dirs, spec)
    u = applied_voltage(t, dirs, 5.0, 0.02)
    assert u[19] == pytest.approx(5.0) and u[20] == pytest.approx(5.0 * (0.02 - 0.03) / 0.05)   # reversal decided at t = 1.0 s acts at 1.02 s
    assert got == energy_terms(t, current, omega, theta, u, spec, v_rms=6.0, period_s=spec.period_s)
    assert got["energy_paper_j"] == pytest.approx(6.0 * 0.05 * np.sum(np.abs(current[:-1] + current[1:]) / 2))


# --- every term against an independent computation (MODEL.md's power balance written out here) ---

def _params():
    p = default_config().plant_spec().params
    return p, p.R * p.R * (p.K1 + p.K2)              # Ks [N m/rad]: both springs through the pinion radius


def test_each_term_against_exact_integrals_of_analytic_signals():
    """Signals with closed-form integrals on a fine grid: each term within 1e-5 of its exact value.

    b w^2 vs b |w|, a doubled kinetic energy or a flipped spring sign each move their term by 30 % or more.
    """
    from dataclasses import replace

    p, Ks = _params()
    spec = replace(default_config().plant_spec(), Tc=2e-3)
    t = np.linspace(0.0, 2.0, 20001)
    w = 2.0 * np.sin(np.pi * t / 4)                   # 0 -> 2 rad/s
    th = t / 2                                        # 0 -> 1 rad
    current = 0.3 * np.cos(np.pi * t)                 # 0.3 -> 0.3 A
    u = np.full(len(t), 6.0)
    e = energy_terms(t, current, w, th, u, spec, v_rms=6.0, period_s=0.05)
    a, c = 5 * np.pi / 4, 3 * np.pi / 4
    sin_cos = 0.5 * ((1 - np.cos(2 * a)) / a - (1 - np.cos(2 * c)) / c)     # int_0^2 sin(pi t/4) cos(pi t) dt
    exact = {
        "input_energy_j": 0.0,                                                # 6 V * 0.3 A * int_0^2 cos(pi t) = 0
        "copper_loss_j": p.Ra * 0.09 * 1.0,                                   # int_0^2 cos^2(pi t) = 1
        "friction_loss_j": p.b * 4.0 * 1.0 + 2e-3 * 2.0 * 4.0 / np.pi,        # b int w^2 + Tc int |w|
        "emf_torque_mismatch_j": (p.Ke - p.Kt) * 2.0 * 0.3 * sin_cos,
        "spring_energy_change_j": 0.5 * Ks * 1.0,
        "kinetic_energy_change_j": 0.5 * p.J * 4.0,
        "magnetic_energy_change_j": 0.0,
    }
    for key, want in exact.items():
        assert e[key] == pytest.approx(want, abs=1e-5 * max(1.0, abs(want))), key
    assert e["balance_residual_j"] == pytest.approx(-sum(v for k, v in exact.items() if k != "input_energy_j"),
                                                    abs=1e-5)


def _reference_replay(spec, dt=1e-3, duration=9.0):
    """The rig's independent plant (solve_ivp) replaying the sketch's 50 ms decisions on a 1 ms grid."""
    from pipeline.model.simulate import sample_times
    from pipeline.rig.plant import simulate_reference

    coarse = simulate(spec, sample_times(duration, spec.period_s))
    t = np.arange(0.0, coarse.t[-1] + 1e-12, dt)
    d = coarse.dir[np.minimum(np.searchsorted(coarse.t, t, side="right") - 1, len(coarse.t) - 1)]
    return simulate_reference(spec, t, dir_log=d, closed_loop=False), d


def test_balance_closes_far_below_the_smallest_term_on_the_reference_plant():
    """On the independent plant sampled at 1 ms the books close to 1e-5 J, 40x below the smallest
    term, over a window ending where angle and velocity are both large (so the stored terms matter)."""
    p, Ks = _params()
    spec = default_config().plant_spec()
    r, d = _reference_replay(spec)
    end = int(np.argmax(np.abs(r.theta * r.omega) * (r.t > 3.0))) + 1
    t, current, w, th, u = r.t[:end], r.current[:end], r.omega[:end], r.theta[:end], d[:end] * spec.v_drive
    e = energy_terms(t, current, w, th, u, spec, v_rms=6.0, period_s=0.05)
    indep = {"input_energy_j": np.sum(u[:-1] * (current[:-1] + current[1:]) / 2 * np.diff(t)),
             "copper_loss_j": p.Ra * np.trapezoid(current ** 2, t),
             "friction_loss_j": p.b * np.trapezoid(w ** 2, t),
             "emf_torque_mismatch_j": (p.Ke - p.Kt) * np.trapezoid(w * current, t),
             "spring_energy_change_j": 0.5 * Ks * (th[-1] ** 2 - th[0] ** 2),
             "kinetic_energy_change_j": 0.5 * p.J * (w[-1] ** 2 - w[0] ** 2),
             "magnetic_energy_change_j": 0.5 * p.La * (current[-1] ** 2 - current[0] ** 2)}
    smallest = min(abs(v) for v in indep.values())
    assert smallest > 4e-4                                   # every term is visible at this window's end
    for key, want in indep.items():
        assert e[key] == pytest.approx(want, rel=1e-9, abs=1e-12), key
    assert abs(e["balance_residual_j"]) < 1e-5 < 0.05 * smallest
