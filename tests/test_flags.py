"""The 0/1 flag convention (systems/flags.py): set above 0.5 only, NaN not set, elementwise on arrays."""

import numpy as np
import pytest

from systems.flags import is_set


@pytest.mark.parametrize("flag, expected", [(1.0, True), (0.0, False), (0.5, False), (0.51, True),
                                            (np.nan, False), (np.inf, True), (-np.inf, False)])
def test_a_flag_is_set_only_above_one_half(flag, expected):
    assert bool(is_set(flag)) is expected
    assert bool(is_set(np.float64(flag))) is expected


def test_arrays_are_read_elementwise():
    np.testing.assert_array_equal(is_set(np.array([[1.0, 0.0], [np.nan, 0.9]])), [[True, False], [False, True]])
