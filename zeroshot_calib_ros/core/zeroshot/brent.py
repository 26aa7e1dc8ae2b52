"""Brent's bracketed root finder without scipy (issue 14: the node's start-up solve must not
import scipy.optimize, ~0.5 s, for a root found in microseconds).

``brentq`` is the algorithm of scipy.optimize.brentq (Charles Harris' C implementation in
scipy/optimize/Zeros/brentq.c), step for step in Python floats, so it returns the same root,
bit for bit, with the same arguments; the errors are those scipy raises (ValueError for a bad
bracket, a NaN value or bad tolerances; RuntimeError when ``maxiter`` is not enough).
"""
from __future__ import annotations

import math
import sys

_EPS = sys.float_info.epsilon


def brentq(f, a: float, b: float, xtol: float = 2e-12, rtol: float = 4 * _EPS, maxiter: int = 100) -> float:
    """A root of ``f`` in [a, b], where f(a) and f(b) have opposite signs (see the module)."""
    if xtol <= 0:
        raise ValueError(f'xtol too small ({xtol:g} <= 0)')
    if rtol < 4 * _EPS:
        raise ValueError(f'rtol too small ({rtol:g} < {4 * _EPS:g})')

    def value(x):
        fx = float(f(x))
        if math.isnan(fx):
            raise ValueError(f'The function value at x={x:f} is NaN; solver cannot continue.')
        return fx

    xpre, xcur = float(a), float(b)
    xblk = fblk = spre = scur = 0.0
    fpre, fcur = value(xpre), value(xcur)
    if fpre == 0:
        return xpre
    if fcur == 0:
        return xcur
    if math.copysign(1.0, fpre) == math.copysign(1.0, fcur):
        raise ValueError('f(a) and f(b) must have different signs')
    for _ in range(maxiter):
        if fpre != 0 and fcur != 0 and math.copysign(1.0, fpre) != math.copysign(1.0, fcur):
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = (xtol + rtol * abs(xcur)) / 2
        sbis = (xblk - xcur) / 2
        if fcur == 0 or abs(sbis) < delta:
            return xcur
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:  # interpolate
                stry = -fcur * (xcur - xpre) / (fcur - fpre)
            else:  # extrapolate
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            if 2 * abs(stry) < min(abs(spre), 3 * abs(sbis) - delta):  # good short step
                spre, scur = scur, stry
            else:  # bisect
                spre = scur = sbis
        else:  # bisect
            spre = scur = sbis
        xpre, fpre = xcur, fcur
        xcur += scur if abs(scur) > delta else (delta if sbis > 0 else -delta)
        fcur = value(xcur)
    raise RuntimeError(f'Failed to converge after {maxiter} iterations, value is {xcur}')
