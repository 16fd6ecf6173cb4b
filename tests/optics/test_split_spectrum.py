"""The largest split margin a filter's limits admit, against a linear program."""

import math

import numpy as np
import pytest
from scipy.optimize import linprog

from metalens_cli.optics.split_spectrum import Band, largest_margin, shift_factor, split_conditions

NM = 1e-9


def _linear_program(n, f, z_near, sensor, width, gap, k):
    """max m over band edges: the paper's inequalities on the oblique bands [k·lo, hi], each
    ≥ m, are linear in (lo_i, w_i, m) once s and k are fixed; so are the limits."""
    s_min, s_max = shift_factor(f, z_near[1]), shift_factor(f, z_near[0])
    lo, w, m = (lambda i: i), (lambda i: n + i), 2 * n  # variable indices, in nm
    rows, bounds = [], []

    def at_least(terms, value):  # Σ c·x ≥ value  →  −Σ c·x ≤ −value
        row = np.zeros(2 * n + 1)
        for index, c in terms:
            row[index] += c
        rows.append(-row)
        bounds.append(-value)

    for i in range(n):
        at_least([(lo(i), k * s_min - 1), (w(i), -1), (m, -1)], 0)  # min_into_stop
        at_least([(w(i), 1)], width / NM)
        if i + 1 < n:
            at_least([(lo(i + 1), k), (lo(i), -s_max), (w(i), -s_max), (m, -1)], 0)  # max_below
            at_least([(lo(i + 1), 1), (lo(i), -1), (w(i), -1)], gap / NM)
    at_least([(lo(0), 1)], sensor[0] / NM)
    at_least([(lo(n - 1), -1), (w(n - 1), -1)], -sensor[1] / NM)
    cost = np.zeros(2 * n + 1)
    cost[m] = -1
    result = linprog(cost, A_ub=np.array(rows), b_ub=np.array(bounds), bounds=[(None, None)] * (2 * n + 1))
    return (-result.fun * NM, result.x) if result.status == 0 else (-math.inf, None)


CASES = [
    (3, 4e-3, (40e-3, 50e-3), (400e-9, 700e-9), 10e-9, 5e-9, 0.9705),  # the quick joint filter's limits
    (3, 4e-3, (40e-3, 50e-3), (400e-9, 700e-9), 10e-9, 5e-9, 1.0),
    (3, 4e-3, (40e-3, 50e-3), (400e-9, 700e-9), 10e-9, 60e-9, 1.0),  # the gaps bind
    (2, 1e-3, (40e-3, 50e-3), (400e-9, 700e-9), 6e-9, 5e-9, 1.0),  # a weak shift: s = 1.02-1.025
    (5, 6e-3, (30e-3, 60e-3), (380e-9, 780e-9), 4e-9, 2e-9, 0.99),
    (3, 1e-3, (40e-3, 50e-3), (400e-9, 700e-9), 10e-9, 5e-9, 0.97),  # k·s < 1: none meets them (m < 0)
]


@pytest.mark.parametrize("case", CASES)
def test_largest_margin_is_the_linear_programs_optimum(case):
    bound = largest_margin(*case)
    optimum, x = _linear_program(*case)
    assert not math.isinf(optimum)
    assert bound == pytest.approx(optimum, abs=1e-13)  # 1e-4 nm
    # the optimum is a filter whose paper margins, evaluated by split_conditions, all reach it
    n = case[0]
    bands = tuple(Band(str(i), x[i] * NM * case[6], (x[i] + x[n + i]) * NM) for i in range(n))
    paper = [c for c in split_conditions(bands, case[1], *case[2], case[3]) if "clear" not in c.name]
    assert min(c.margin_m for c in paper) == pytest.approx(bound, abs=1e-13)


def test_bands_that_do_not_fit_have_no_margin():
    assert _linear_program(3, 4e-3, (40e-3, 50e-3), (400e-9, 700e-9), 10e-9, 200e-9, 1.0)[1] is None
    assert largest_margin(3, 4e-3, (40e-3, 50e-3), (400e-9, 700e-9), 10e-9, 200e-9, 1.0) == -math.inf
    assert largest_margin(3, 4e-3, (40e-3, 50e-3), (400e-9, 700e-9), 101e-9, 0.0, 1.0) == -math.inf
