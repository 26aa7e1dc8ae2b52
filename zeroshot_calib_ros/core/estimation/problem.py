"""A problem: terms stacked and whitened over one parameter layout, solved by least squares.

The cost is sum_t sum_g rho_t(|r_tg / sigma_t|^2) over the terms t and their residual groups g
(a pixel is one group of 2), rho_t the term's robust loss scaled to ``loss_scale`` sigmas
(``soft_l1``: 2 c^2 (sqrt(1 + s / c^2) - 1), ``cauchy``: c^2 log(1 + s / c^2); identity for
least squares). scipy's ``least_squares`` applies one loss to every residual, so each robust
group is rewritten as r sqrt(rho(s) / s), whose square is rho(s) (the corrected residual of
Triggs et al., as Ceres does), and the solver runs plain least squares on that. Jacobians are
forward differences with the layout's steps, so every term only needs ``residuals(camera)``.

A Jacobian's columns are independent evaluations of the problem: inside ``jacobian_threads(n)``
they are computed in ``n`` threads (numpy releases the GIL over arrays of the sizes line fits
have), with the same values in the same order as in one thread; terms must therefore keep no
state between ``residuals`` calls (none does).
"""
from __future__ import annotations

from concurrent.futures import Executor, ThreadPoolExecutor
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Iterator, List, Optional

import numpy as np
from scipy.optimize import least_squares


_JACOBIAN_POOL: ContextVar[Optional[Executor]] = ContextVar('zeroshot_jacobian_pool', default=None)


@contextmanager
def jacobian_threads(threads: int) -> Iterator[None]:
    """Within the block (in this thread), ``Problem.jacobian`` computes its columns in ``threads``
    threads; 1 or less: in the calling thread, as outside the block."""
    if threads <= 1:
        yield
        return
    with ThreadPoolExecutor(max_workers=int(threads), thread_name_prefix='jacobian') as pool:
        token = _JACOBIAN_POOL.set(pool)
        try:
            yield
        finally:
            _JACOBIAN_POOL.reset(token)


def robust_factor(s: np.ndarray, loss: Optional[str], c: float) -> np.ndarray:
    """sqrt(rho(s) / s) of squared whitened group norms ``s`` (1 where s = 0 or no loss)."""
    if loss is None:
        return np.ones_like(s)
    c2 = c * c
    with np.errstate(divide='ignore', invalid='ignore'):
        if loss == 'soft_l1':
            rho = 2.0 * c2 * (np.sqrt(1.0 + s / c2) - 1.0)
        elif loss == 'cauchy':
            rho = c2 * np.log1p(s / c2)
        else:
            raise ValueError(f"loss = {loss!r} is invalid: allowed: None, 'soft_l1', 'cauchy'")
        factor = np.sqrt(rho / s)
    return np.where(s > 0, factor, 1.0)


@dataclass
class ProblemSolution:
    x: np.ndarray
    cost: float
    """Half the sum of squared (robust-corrected) whitened residuals, as least_squares reports."""
    jacobian: np.ndarray
    """Whitened, robust-corrected Jacobian at x."""
    success: bool
    message: str
    evaluations: int


class Problem:
    """Terms over a layout (module docstring)."""

    def __init__(self, layout, terms: List):
        self.layout = layout
        self.terms = list(terms)
        self._last = (None, None, None)

    def whitened(self, x, robust: bool = True) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        # the terms are in the key: a caller may add a term between two calls at the same x
        key = (robust, tuple(map(id, self.terms)))
        last_x, last_key, last_r = self._last
        if last_x is not None and last_key == key and np.array_equal(last_x, x):
            return last_r
        r = self._evaluate(x, robust)
        self._last = (x.copy(), key, r)
        return r

    def _evaluate(self, x, robust: bool) -> np.ndarray:
        """The whitened residuals at ``x``, without the cache (safe in several threads at once)."""
        camera = self.layout.camera(x)
        return np.concatenate([self._whiten(t, t.residuals(camera), robust) for t in self.terms])

    @staticmethod
    def _whiten(term, r, robust):
        w = np.asarray(r, dtype=float) / term.sigma
        if robust and term.loss is not None:
            g = w.reshape(-1, term.group)
            s = np.sum(g * g, axis=1)
            w = (g * robust_factor(s, term.loss, term.loss_scale)[:, None]).ravel()
        return w

    def term_residuals(self, x) -> dict:
        """Unwhitened residuals of each term by name (the last of equal names wins)."""
        camera = self.layout.camera(x)
        return {t.name: t.residuals(camera) for t in self.terms}

    def jacobian(self, x, robust: bool = True, r0=None) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        r0 = self.whitened(x, robust).copy() if r0 is None else r0
        steps = self.layout.steps(x)

        def column(j):
            xp = x.copy()
            xp[j] += steps[j]
            return (self._evaluate(xp, robust) - r0) / steps[j]

        pool = _JACOBIAN_POOL.get()
        columns = pool.map(column, range(x.size)) if pool is not None else map(column, range(x.size))
        J = np.empty((r0.size, x.size))
        for j, values in enumerate(columns):
            J[:, j] = values
        return J

    def solve(self, x0, max_nfev: int = 60, ftol: float = 1e-10, xtol: float = 1e-10) -> ProblemSolution:
        x0 = np.asarray(x0, dtype=float)
        result = least_squares(self.whitened, x0, jac=lambda x: self.jacobian(x), method='trf',
                               x_scale='jac', max_nfev=max_nfev, ftol=ftol, xtol=xtol, gtol=1e-12)
        return ProblemSolution(result.x, float(result.cost), result.jac, bool(result.success),
                               str(result.message), int(result.nfev))
