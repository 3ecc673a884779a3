"""agv_core.numerics.ode: RK4 with step doubling."""

import math

import pytest

from agv_core.numerics.ode import rk4_doubling


def test_a_right_hand_side_that_always_fails_raises_even_without_error_bound():
    """An infinite tolerance accepts any estimate, but not a step that was never computed:
    the failure is reported, no state of None is returned."""
    def blows_up(y):
        raise ZeroDivisionError("division by zero in the model")

    with pytest.raises(FloatingPointError, match="division by zero in the model"):
        rk4_doubling(blows_up, [1.0], 0.1, math.inf)


def test_an_infinite_tolerance_takes_the_first_pair_of_trials():
    y, n = rk4_doubling(lambda y: [-y[0]], [1.0], 0.1, math.inf)
    assert n == 2
    assert y == pytest.approx([math.exp(-0.1)], rel=1e-8)
