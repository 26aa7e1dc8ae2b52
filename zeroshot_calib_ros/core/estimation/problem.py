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
state between ``residuals`` calls. The line terms keep none (refine uses the threads); the board's
corner term keeps its last poses as the next pose solve's start (``CornerTerm``), so board fits
compute their columns in the calling thread.

The solver's large products and decompositions (the trust region's SVD of the Jacobian, tens of
thousands of rows) go to BLAS, which, when it is OpenBLAS, starts a thread per core for each;
inside ``one_blas_thread()`` they run in the calling thread: a fit's parallelism is its
Jacobian's threads, and OpenBLAS's threads waiting for one another on cores that other work
holds made each SVD ten times slower (0.1 s instead of 0.01 s on 2 busy cores). The numbers are
the same with one thread as with several.
"""
from __future__ import annotations

import ctypes
import os
import threading
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


def openblas_thread_controls() -> List[tuple]:
    """(get, set) of the thread count of every OpenBLAS loaded in this process (numpy's, SciPy's
    and OpenCV's own copies, or the system's ``libblas.so.3`` when it is OpenBLAS): the shared
    libraries of ``/proc/self/maps`` with "openblas" in their path that export
    ``[scipy_]openblas_{get,set}_num_threads[64_]``. Empty where that file cannot be read (not
    Linux) or no OpenBLAS is loaded (another BLAS: nothing is changed)."""
    try:
        with open('/proc/self/maps') as maps:
            paths = sorted({fields[5].strip() for fields in (line.split(None, 5) for line in maps) if len(fields) == 6})
    except OSError:
        return []
    controls = []
    for path in paths:
        if not path.startswith('/') or 'openblas' not in path.lower() or not os.path.isfile(path):
            continue
        try:
            library = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix, suffix in (('', ''), ('scipy_', '64_'), ('scipy_', ''), ('', '64_')):
            get = getattr(library, f'{prefix}openblas_get_num_threads{suffix}', None)
            put = getattr(library, f'{prefix}openblas_set_num_threads{suffix}', None)
            if get is not None and put is not None:
                controls.append((get, put))
                break
    return controls


_BLAS_LOCK = threading.Lock()
_BLAS_HELD = {'depth': 0, 'restore': []}


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Within the block, every OpenBLAS loaded runs each call in the calling thread (module
    docstring); the thread counts before are restored when the last of nested or concurrent
    blocks ends. Nothing changes where no OpenBLAS is found."""
    with _BLAS_LOCK:
        if _BLAS_HELD['depth'] == 0:
            restore = []
            for get, put in openblas_thread_controls():
                count = int(get())
                if count != 1:
                    put(1)
                    restore.append((put, count))
            _BLAS_HELD['restore'] = restore
        _BLAS_HELD['depth'] += 1
    try:
        yield
    finally:
        with _BLAS_LOCK:
            _BLAS_HELD['depth'] -= 1
            if _BLAS_HELD['depth'] == 0:
                for put, count in reversed(_BLAS_HELD['restore']):
                    put(count)
                _BLAS_HELD['restore'] = []


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
