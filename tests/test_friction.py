"""CoulombViscousFriction: tau_f(dq) = mu_C sgn_band(dq) + d_v dq, and the regressor (15)."""

from __future__ import annotations

import numpy as np
import pytest

from reflexarm.errors import ConfigError
from reflexarm.robots import CoulombViscousFriction
from reflexarm.robots.friction import DEFAULT_VELOCITY_BAND

#: Table I of the paper (Atlas left arm), typed here: Coulomb mu_C [Nm] and viscous d_v [Nms/rad].
MU_C = np.array([2.0, 6.7, 10.3, 6.1, 0.1, 0.1, 3.1])
D_V = np.array([1.3, 0.9, 1.6, 2.7, 0.5, 0.2, 0.2])

#: Round-off of a few multiply-adds on torques of O(10) Nm.
ROUND_OFF = 1e-13


@pytest.fixture
def friction() -> CoulombViscousFriction:
    return CoulombViscousFriction(MU_C, D_V)


def test_smooth_sign_is_linear_inside_the_band(friction: CoulombViscousFriction) -> None:
    band = friction.velocity_band
    assert band == DEFAULT_VELOCITY_BAND
    for fraction in (-0.9, -0.25, 0.0, 0.1, 0.5, 1.0):
        dq = np.full(7, fraction * band)
        np.testing.assert_allclose(
            friction.compute_torque(dq), MU_C * fraction + D_V * dq, rtol=0, atol=ROUND_OFF, err_msg=f"{fraction=}"
        )
    # linear: equal steps in dq give equal steps in tau_f
    steps = np.diff([friction.compute_torque(np.full(7, x * band)) for x in np.linspace(-1, 1, 9)], axis=0)
    np.testing.assert_allclose(steps, np.broadcast_to(steps[0], steps.shape), rtol=0, atol=ROUND_OFF)


def test_smooth_sign_is_the_sign_outside_the_band(friction: CoulombViscousFriction) -> None:
    band = friction.velocity_band
    for dq_scalar in (-3.0, -1.0001 * band, 1.0001 * band, 0.4, 12.0):
        dq = np.full(7, dq_scalar)
        np.testing.assert_allclose(
            friction.compute_torque(dq), MU_C * np.sign(dq_scalar) + D_V * dq, rtol=0, atol=ROUND_OFF
        )


def test_friction_is_continuous_odd_and_dissipative(friction: CoulombViscousFriction) -> None:
    rng = np.random.default_rng(0)
    dq = rng.normal(0, 0.05, (200, 7))  # many samples inside and around the band
    tau = np.array([friction.compute_torque(v) for v in dq])
    np.testing.assert_array_equal(np.array([friction.compute_torque(-v) for v in dq]), -tau)
    assert np.all(tau * dq >= 0.0), "friction must never feed energy in"
    # Lipschitz across the band edges: |d tau / d dq| <= mu_C / band + d_v
    dq_fine = np.linspace(-0.1, 0.1, 2001)
    tau_fine = np.array([friction.compute_torque(np.full(7, v)) for v in dq_fine])
    slope = np.abs(np.diff(tau_fine, axis=0)) / np.diff(dq_fine)[:, None]
    assert np.all(slope <= MU_C / friction.velocity_band + D_V + 1e-6)


def test_compute_torque_into_equals_compute_torque(friction: CoulombViscousFriction) -> None:
    rng = np.random.default_rng(1)
    out = np.empty(7)
    for scale in (0.005, 0.05, 2.0):  # mostly inside, around and outside the band
        for _ in range(20):
            dq = rng.normal(0, scale, 7)
            returned = friction.compute_torque_into(dq, out)
            assert returned is out
            # same operations on the same numbers: equal to round-off
            np.testing.assert_allclose(out, friction.compute_torque(dq), rtol=0, atol=ROUND_OFF)
    with pytest.raises(ConfigError, match="out must not be dq"):
        friction.compute_torque_into(out, out)


def test_regressor_times_parameters_is_the_exact_sign_friction(friction: CoulombViscousFriction) -> None:
    """Phi_f(dq) (d_v, mu_C) = d_v dq + mu_C sign(dq), eq. (15): the exact sign, no band."""
    rng = np.random.default_rng(2)
    params = friction.parameters()
    np.testing.assert_array_equal(params, np.concatenate([D_V, MU_C]))  # order (d_v, mu_C)
    for scale in (0.005, 1.0):
        dq = rng.normal(0, scale, 7)
        Phi = friction.compute_regressor(dq)
        assert Phi.shape == (7, 14)
        np.testing.assert_allclose(Phi @ params, D_V * dq + MU_C * np.sign(dq), rtol=0, atol=ROUND_OFF)
    dq = np.array([0.5, -0.5, 1.0, -2.0, 0.03, -0.03, 3.0])  # all outside the band: same as compute_torque
    np.testing.assert_allclose(friction.compute_regressor(dq) @ params, friction.compute_torque(dq), atol=ROUND_OFF)
    np.testing.assert_array_equal(friction.compute_regressor(np.zeros(7)) @ params, 0.0)  # sign(0) = 0


@pytest.mark.parametrize("name", ["coulomb", "viscous"])
def test_negative_coefficients_are_rejected_by_name(name: str) -> None:
    bad = {"coulomb": MU_C.copy(), "viscous": D_V.copy()}
    bad[name][3] = -0.1
    with pytest.raises(ConfigError, match=f"{name} must be non-negative; got .*-0.1"):
        CoulombViscousFriction(bad["coulomb"], bad["viscous"])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"coulomb": MU_C, "viscous": D_V[:5]}, r"viscous must have shape \(7,\) .* got shape \(5,\)"),
        ({"coulomb": MU_C, "viscous": D_V, "velocity_band": 0.0}, "velocity_band must be a positive number; got 0.0"),
        ({"coulomb": MU_C, "viscous": D_V, "velocity_band": "fast"}, "velocity_band must be a positive number"),
        ({"coulomb": [1.0, np.nan], "viscous": 0.0}, "coulomb must be finite"),
        ({"coulomb": MU_C, "viscous": D_V, "velocity_band": -0.02}, "velocity_band must be a positive number"),
    ],
)
def test_bad_arguments_name_the_parameter(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        CoulombViscousFriction(**kwargs)  # type: ignore[arg-type]


def test_scalar_viscous_broadcasts_and_zeros() -> None:
    f = CoulombViscousFriction(np.array([1.0, 2.0, 3.0]), np.asarray(0.5))  # a 0-d viscous broadcasts
    np.testing.assert_array_equal(f.viscous, [0.5, 0.5, 0.5])
    assert f.n == 3
    zero = CoulombViscousFriction.zeros(4)
    assert zero.n == 4
    np.testing.assert_array_equal(zero.compute_torque(np.array([-1.0, 0.0, 0.01, 5.0])), 0.0)


def test_scaled_multiplies_each_coefficient(friction: CoulombViscousFriction) -> None:
    c_scale = np.linspace(0.9, 1.1, 7)
    scaled = friction.scaled(c_scale, 1.05)
    np.testing.assert_allclose(scaled.coulomb, MU_C * c_scale, rtol=1e-15)
    np.testing.assert_allclose(scaled.viscous, D_V * 1.05, rtol=1e-15)
    assert scaled.velocity_band == friction.velocity_band
    np.testing.assert_array_equal(friction.coulomb, MU_C)  # the original is unchanged
    with pytest.raises(ConfigError, match="coulomb must be non-negative"):
        friction.scaled(-1.0, 1.0)


def test_value_semantics(friction: CoulombViscousFriction) -> None:
    """Equal coefficients compare equal and hash alike; the arrays cannot be changed behind the model's back."""
    twin = CoulombViscousFriction(MU_C.tolist(), D_V.tolist())
    assert twin == friction and hash(twin) == hash(friction)
    assert friction != friction.scaled(1.0, 2.0)
    assert friction != CoulombViscousFriction(MU_C, D_V, velocity_band=0.05)
    with pytest.raises(ValueError, match="read-only"):
        friction.coulomb[0] = -1.0
    source = MU_C.copy()
    owned = CoulombViscousFriction(source, D_V)
    source[0] = 99.0  # the model keeps its own copy
    assert owned.coulomb[0] == MU_C[0]
