r"""Fast embedded-style RTI path: no cvxpy, condensed QP, native solvers (issue 6).

The same robust MPC as :class:`~ltv_lstm_mpc.mpc.rti.RobustMPC` (eq. optimization, one
real-time iteration on the shifted candidate of SPEC 4), organised the way embedded
RTI codes are (acados ``prepare`` / ``feedback``):

``prepare(x_bar, u_bar, y0, e_hat)``
    before the estimate arrives: simulate the candidate
    :math:`\tilde u = (u^*_{1|k-1}, \dots, u^*_{N-1|k-1}, \bar u_k)` from the predicted
    state, linearize the whole horizon in one batched pass (analytic Jacobians of
    eq. lstm), and condense into preallocated arrays

    .. math::

        \delta x_i = \Phi_i\, \delta x_0 + \Gamma_i\, \delta u, \qquad
        \min_{\delta u} \tfrac12 \delta u^\top H \delta u
        + (g_0 + F \delta x_0)^\top \delta u

    with the tightened output rows of eq. (optimization_constraint_yub)/(ylb) and the
    terminal set as rows in :math:`\delta u` and the input box as simple bounds;
``feedback(x_hat)``
    insert :math:`\delta x_0 = \hat x_k - \tilde x_0` (one matrix-vector product per
    data vector), solve with a native dense solver (DAQP, quadprog, ProxQP, PIQP dense,
    OSQP with a fixed pattern and ``update``), re-simulate the plan on the true LSTM.

QP-only solvers cannot take the terminal cones, so the terminal set and cost get the
conservative replacement of SPEC 4, exactly the math of
:class:`~ltv_lstm_mpc.mpc.sparse.TerminalBoxReformulation` (box inside
:math:`\mathcal X_f(k)`, cost bound
:math:`(P_{11}+P_{12})\|c_N-\bar c\|^2 + (P_{22}+P_{12})\|h_N-\bar h\|^2`); its name is
recorded in every :class:`~ltv_lstm_mpc.mpc.rti.MPCSolution`.

:class:`FastOffsetFreeController` fuses the whole Fig. 1 step (observer eq.
lstm_observer, warm-started Newton for eq. reference_calculation, the RTI step) with the
same records as :class:`~ltv_lstm_mpc.loop.controller.OffsetFreeController`.
"""

from __future__ import annotations

import abc
import math
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.certificates.certify import Certification, certify
from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError, LtvMpcError, SolverNotFound
from ltv_lstm_mpc.loop.controller import OffsetFreeController
from ltv_lstm_mpc.loop.reference import ReferenceCalculator, ReferenceSolution
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc.rti import (
    MPCConfig,
    MPCSolution,
    checked_vector,
    precheck_status,
    shifted_candidate,
)
from ltv_lstm_mpc.mpc.sparse import FHOCPSubproblem

__all__ = [
    "FAST_SOLVERS",
    "FastOffsetFreeController",
    "FastReferenceCalculator",
    "FastRobustMPC",
    "LSTMKernel",
    "fast_solvers",
]

FloatArray = NDArray[np.float64]

#: Native dense solvers of the fast path (``qpsolvers:<name>`` is accepted too).
FAST_SOLVERS = ("daqp", "quadprog", "proxqp", "piqp", "osqp")
_MODULE = {"daqp": "daqp", "quadprog": "quadprog", "proxqp": "proxsuite", "piqp": "piqp"}
_MODULE["osqp"] = "osqp"


def fast_solvers() -> list[str]:
    """The native solvers of :data:`FAST_SOLVERS` that import."""
    import importlib.util

    return [s for s in FAST_SOLVERS if importlib.util.find_spec(_MODULE[s]) is not None]


# =====================================================================================
# LSTM kernel
# =====================================================================================
class Trajectory:
    r"""Preallocated horizon buffers of :class:`LSTMKernel` with precomputed views.

    Attributes
    ----------
    S : ndarray, shape (N + 1, 2n + m + 1)
        Rows :math:`[c_k, h_k, u_k, 1]`: the state is ``S[:, :2n]``, the input
        ``S[:, 2n:2n+m]``, and the gate input :math:`[h_k; u_k; 1]` is ``S[k, n:]``.
    T : ndarray, shape (N, 4n)
        Gate activations :math:`[f, i, o, g]` of each step.
    TC : ndarray, shape (N, n)
        :math:`\tanh(c_{k+1})`.
    J : ndarray, shape (N, 2n, 2n + m)
        Jacobians :math:`[A_k\; B_k]` (filled by :meth:`LSTMKernel.jacobians`).
    """

    def __init__(self, n: int, m: int, N: int) -> None:
        n2, n3 = 2 * n, 3 * n
        self.N, self.n, self.m = N, n, m
        self.S = np.zeros((N + 1, n2 + m + 1))
        self.S[:, -1] = 1.0
        self.T = np.zeros((N, 4 * n))
        self.TC = np.zeros((N, n))
        self.J = np.zeros((N, n2, n2 + m))
        self.tmp = np.empty(n)
        S, T, TC = self.S, self.T, self.TC
        self.views = [
            (
                S[k, n:],  # [h; u; 1]
                T[k],
                T[k, :n3],  # sigmoid rows (pre-activation, then activation)
                T[k, n3:],  # g rows
                T[k, :n],  # f
                T[k, n : 2 * n],  # i
                T[k, 2 * n : n3],  # o
                S[k, :n],  # c_k
                S[k + 1, :n],  # c_{k+1}
                S[k + 1, n:n2],  # h_{k+1}
                TC[k],
            )
            for k in range(N)
        ]
        self.Dv = np.empty((N, 4 * n))
        self.dh_dc = np.empty((N, n))
        cols = n2 + m
        self.J_diag = self.J.reshape(N, -1)[:, : n * (cols + 1) : cols + 1]  # J[k, a, a], a < n

    @property
    def x(self) -> FloatArray:
        """States, view ``(N + 1, 2n)``."""
        return self.S[:, : 2 * self.n]

    @property
    def u(self) -> FloatArray:
        """Inputs, view ``(N + 1, m)`` (row N unused)."""
        return self.S[:, 2 * self.n : 2 * self.n + self.m]


class LSTMKernel:
    r"""Lean numpy kernels of eq. (lstm) writing into a :class:`Trajectory`.

    :meth:`rollout` simulates and stores the gate activations; :meth:`jacobians`
    (eq. jacobian) reuses them for the whole horizon in one batched pass. No
    validation, no allocation per step: the real-time building block.
    """

    def __init__(self, model: LSTMModel) -> None:
        from scipy.special import expit

        self.n, self.m, self.p = model.n, model.m, model.p
        self.WU_raw = np.hstack([model._U_gates, model._W_gates])  # (4n, n + m)
        self.WU = np.ascontiguousarray(np.hstack([self.WU_raw, model._b_gates[:, None]]))
        self._expit = expit

    def trajectory(self, N: int) -> Trajectory:
        """New preallocated buffers for a horizon of N steps."""
        return Trajectory(self.n, self.m, N)

    def rollout(self, traj: Trajectory, k0: int, k1: int, extra: FloatArray | None = None) -> None:
        r"""Simulate steps ``k0..k1-1`` in place (inputs ``traj.u[k]`` given).

        ``extra`` is added to the gate pre-activations of every step (the observer's
        :math:`L (y - \hat y)` terms, eq. lstm_observer).
        """
        WU, expit, tanh, mul, dot = self.WU, self._expit, np.tanh, np.multiply, np.dot
        tmp = traj.tmp
        views = traj.views
        for k in range(k0, k1):
            hu1, t, s, g, f, i, o, c, cn, hn, tc = views[k]
            dot(WU, hu1, out=t)
            if extra is not None:
                t += extra
            expit(s, out=s)
            tanh(g, out=g)
            mul(f, c, out=cn)
            mul(i, g, out=tmp)
            cn += tmp
            tanh(cn, out=tc)
            mul(o, tc, out=hn)

    def jacobians(self, traj: Trajectory) -> None:
        r"""Batched :math:`[A_k\; B_k] = \partial f / \partial [c; h; u]` at the stored steps.

        With the gate-wise derivatives
        :math:`D = [c\,\sigma_f', g\,\sigma_i', \tanh(c^+)\sigma_o', i (1-g^2)]`,
        :math:`\partial c^+/\partial[h; u] = \sum_{g \in f,i,c} D_g [U_g\; W_g]`,
        :math:`\partial c^+/\partial c = \mathrm{diag}(f)` and
        :math:`\partial h^+ = o(1-\tanh^2 c^+)\,\partial c^+ + D_o [0\; U_o\; W_o]`.
        """
        n = self.n
        n3 = 3 * n
        S, T, TC, J, Dv, dh_dc = traj.S, traj.T, traj.TC, traj.J, traj.Dv, traj.dh_dc
        N = J.shape[0]
        sig = T[:, :n3]
        Ds = Dv[:, :n3]
        np.subtract(1.0, sig, out=Ds)
        Ds *= sig
        Dv[:, :n] *= S[:N, :n]
        Dv[:, n : 2 * n] *= T[:, n3:]
        Dv[:, 2 * n : n3] *= TC
        Dc = Dv[:, n3:]
        np.multiply(T[:, n3:], T[:, n3:], out=Dc)
        np.subtract(1.0, Dc, out=Dc)
        Dc *= T[:, n : 2 * n]
        P = Dv[:, :, None] * self.WU_raw  # (N, 4n, n + m)
        Jc = J[:, :n, :]
        np.add(P[:, :n], P[:, n : 2 * n], out=Jc[:, :, n:])
        Jc[:, :, n:] += P[:, n3:]
        traj.J_diag[:] = T[:, :n]
        np.multiply(TC, TC, out=dh_dc)
        np.subtract(1.0, dh_dc, out=dh_dc)
        dh_dc *= T[:, 2 * n : n3]
        np.multiply(dh_dc[:, :, None], Jc, out=J[:, n:, :])
        J[:, n:, n:] += P[:, 2 * n : n3]


# =====================================================================================
# Reference calculator, warm-started Newton
# =====================================================================================
class FastReferenceCalculator:
    r"""Warm-started chord-Newton for eq. (reference_calculation) on the lean kernel.

    Solves :math:`F(\bar x, \bar u) = [f(\bar x, \bar u) - \bar x;\;
    W_y \bar h + b_y - (y^0 - \hat d)] = 0` starting from the previous solution. The
    equilibrium moves little between samples, so the inverse Jacobian of eq. (jacobian)
    is kept from the last factorization (chord method: one residual evaluation per
    iteration) and refreshed only when the contraction is slower than 1e-2 per
    iteration. At steady state the call is one residual check. When an iteration with
    a fresh Jacobian does not decrease the residual, or there is no previous solution,
    it falls back to :class:`~ltv_lstm_mpc.loop.reference.ReferenceCalculator` (damped
    Newton with grid restarts). ``jacobian_condition`` is NaN on the fast path.

    Parameters
    ----------
    model : LSTMModel
    u_max : float
    tol : float
        Convergence tolerance on :math:`\|F\|_\infty` (as ReferenceCalculator).
    max_iter : int
        Chord iterations before falling back.
    """

    def __init__(
        self, model: LSTMModel, *, u_max: float = 1.0, tol: float = 1e-10, max_iter: int = 12
    ) -> None:
        model.require_square()
        self.model = model
        self.kernel = LSTMKernel(model)
        self.u_max = float(u_max)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.slow = ReferenceCalculator(model, u_max=u_max, tol=tol, strict=False)
        n, m = model.n, model.m
        self._n2 = 2 * n
        self._traj = self.kernel.trajectory(1)
        self._z_view = self._traj.S[0, : 2 * n + m]
        self._jac = np.zeros((2 * n + m, 2 * n + m))
        self._jac[2 * n :, n : 2 * n] = model.W_y
        self._F = np.empty(2 * n + m)
        self._idx = np.arange(2 * n)
        self._W_y = model.W_y
        self._b_y = model.b_y
        self._Jinv: FloatArray | None = None
        self._last: FloatArray | None = None  # z = [x_bar; u_bar]
        self._last_target: FloatArray | None = None
        #: Jacobian factorizations / fallbacks to the damped solver so far.
        self.counts = {"factorizations": 0, "fallbacks": 0}

    def reset(self) -> None:
        """Forget the warm start."""
        self._last = None
        self._last_target = None
        self._Jinv = None
        self.slow.reset()

    def _residual(self, z: FloatArray, target: FloatArray) -> float:
        n, n2 = self.model.n, self._n2
        self._z_view[:] = z
        self.kernel.rollout(self._traj, 0, 1)
        F = self._F
        np.subtract(self._traj.S[1, :n2], z[:n2], out=F[:n2])
        np.dot(self._W_y, z[n:n2], out=F[n2:])
        F[n2:] += self._b_y
        F[n2:] -= target
        return float(np.abs(F).max())

    def _factorize(self) -> None:
        """Inverse Jacobian at the point of the last residual evaluation."""
        self.kernel.jacobians(self._traj)
        jac = self._jac
        jac[: self._n2] = self._traj.J[0]
        jac[self._idx, self._idx] -= 1.0
        self._Jinv = np.linalg.inv(jac)
        self.counts["factorizations"] += 1

    def solve(self, y0: FloatArray, d_hat: FloatArray) -> ReferenceSolution:
        """Solve for :math:`(\bar x, \bar u)` given normalized ``y0`` and ``d_hat``."""
        target = y0 - d_hat
        converged = False
        iterations = 0
        norm = np.inf
        z = self._last
        n2 = self._n2
        if z is not None:
            if self._Jinv is not None and self._last_target is not None:
                # Implicit-function predictor (Lemma 5): dz = -J^{-1} dF = J^{-1}[0; dt].
                z = z + self._Jinv[:, n2:] @ (target - self._last_target)
            norm = self._residual(z, target)
            fresh = False
            while norm >= self.tol and iterations < self.max_iter:
                if self._Jinv is None:
                    self._factorize()
                    fresh = True
                assert self._Jinv is not None
                z_new = z - self._Jinv @ self._F
                iterations += 1
                norm_new = self._residual(z_new, target)
                if not norm_new < norm:
                    if fresh:
                        break  # Newton itself fails here: fall back
                    self._Jinv = None
                    norm = self._residual(z, target)  # restore the state at z
                    continue
                if norm_new > 1e-2 * norm:
                    self._Jinv = None  # slow contraction: refactorize at z_new
                z, norm, fresh = z_new, norm_new, False
            converged = norm < self.tol
        if not converged:
            self.counts["fallbacks"] += 1
            warm = None if self._last is None else (self._last[:n2], self._last[n2:])
            slow = self.slow.solve(y0, d_hat, warm=warm)
            self._Jinv = None
            if slow.ok:
                self._last = np.concatenate([slow.x_bar, slow.u_bar])
                self._last_target = target
            return slow
        assert z is not None
        u_bar = z[n2:].copy()
        admissible = bool(np.abs(u_bar).max() <= self.u_max * (1 + 1e-12))
        if admissible:
            self._last = z
            self._last_target = target
        return ReferenceSolution(
            x_bar=z[:n2].copy(),
            u_bar=u_bar,
            residual=norm,
            jacobian_condition=float("nan"),
            u_admissible=admissible,
            converged=True,
            iterations=iterations,
        )


# =====================================================================================
# Dense QP backends:  min 1/2 x'Hx + f'x  s.t.  lo <= A x <= up,  lb <= x <= ub
# =====================================================================================
class _DenseQP(abc.ABC):
    """One persistent workspace per structure key; returns (status, x, iterations)."""

    name = ""

    def __init__(self, tolerance: float, settings: Mapping[str, Any]) -> None:
        self.tolerance = tolerance
        self.settings = dict(settings)

    @abc.abstractmethod
    def solve(
        self,
        key: str,
        H: FloatArray,
        f: FloatArray,
        A: FloatArray,
        lo: FloatArray,
        up: FloatArray,
        lb: FloatArray,
        ub: FloatArray,
    ) -> tuple[str, FloatArray | None, int]:
        """Solve the dense QP of this workspace: (status name, x or None, iterations)."""


class _Daqp(_DenseQP):
    name = "daqp"

    def __init__(self, tolerance: float, settings: Mapping[str, Any]) -> None:
        from ltv_lstm_mpc.solvers.tolerances import solver_options

        super().__init__(tolerance, settings)
        self.options = solver_options("daqp", tolerance, settings)
        import daqp

        self._solve = daqp.solve
        self._bu: dict[str, FloatArray] = {}
        self._bl: dict[str, FloatArray] = {}
        self._sense: dict[str, NDArray[np.int32]] = {}

    def solve(
        self,
        key: str,
        H: FloatArray,
        f: FloatArray,
        A: FloatArray,
        lo: FloatArray,
        up: FloatArray,
        lb: FloatArray,
        ub: FloatArray,
    ) -> tuple[str, FloatArray | None, int]:
        nv = f.shape[0]
        bu = self._bu.get(key)
        if bu is None or bu.shape[0] != nv + A.shape[0]:
            bu = self._bu[key] = np.empty(nv + A.shape[0])
            self._bl[key] = np.empty(nv + A.shape[0])
            self._sense[key] = np.zeros(nv + A.shape[0], dtype=np.int32)
        bl = self._bl[key]
        bu[:nv] = ub
        bu[nv:] = up
        bl[:nv] = lb
        bl[nv:] = lo
        x, _, exitflag, info = self._solve(H, f, A, bu, bl, self._sense[key], **self.options)
        if exitflag in (1, 2):
            return "optimal", np.asarray(x, dtype=np.float64), int(info["iterations"])
        status = {-1: "infeasible", -4: "max_iter"}.get(int(exitflag), "failed")
        return status, None, int(info["iterations"])


class _Quadprog(_DenseQP):
    name = "quadprog"

    def __init__(self, tolerance: float, settings: Mapping[str, Any]) -> None:
        super().__init__(tolerance, settings)
        import quadprog

        self._solve = quadprog.solve_qp

    def solve(
        self,
        key: str,
        H: FloatArray,
        f: FloatArray,
        A: FloatArray,
        lo: FloatArray,
        up: FloatArray,
        lb: FloatArray,
        ub: FloatArray,
    ) -> tuple[str, FloatArray | None, int]:
        nv = f.shape[0]
        eye = np.eye(nv)
        C = np.vstack([eye, -eye, A, -A]).T
        b = np.concatenate([lb, -ub, lo, -up])
        keep = np.isfinite(b)
        try:
            x, _, _, iters, _, _ = self._solve(H, -f, np.ascontiguousarray(C[:, keep]), b[keep])
        except ValueError as error:
            status = "infeasible" if "constraints are inconsistent" in str(error) else "failed"
            return status, None, 0
        return "optimal", np.asarray(x, dtype=np.float64), int(iters[0])


class _Proxqp(_DenseQP):
    name = "proxqp"

    def __init__(self, tolerance: float, settings: Mapping[str, Any]) -> None:
        from ltv_lstm_mpc.solvers.tolerances import solver_options

        super().__init__(tolerance, settings)
        self.options = solver_options("proxqp", tolerance, settings)
        import proxsuite

        self._px = proxsuite.proxqp
        self._qp: dict[str, Any] = {}

    def solve(
        self,
        key: str,
        H: FloatArray,
        f: FloatArray,
        A: FloatArray,
        lo: FloatArray,
        up: FloatArray,
        lb: FloatArray,
        ub: FloatArray,
    ) -> tuple[str, FloatArray | None, int]:
        nv, mA = f.shape[0], A.shape[0]
        qp = self._qp.get(key)
        C = A if mA else None
        if qp is None or qp.model.dim != nv or qp.model.n_in != mA:
            qp = self._px.dense.QP(nv, 0, mA, True)
            for name, value in self.options.items():
                setattr(qp.settings, name, value)
            qp.settings.initial_guess = self._px.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
            qp.init(H, f, None, None, C, lo if mA else None, up if mA else None, lb, ub)
            self._qp[key] = qp
        else:
            qp.update(H, f, None, None, C, lo if mA else None, up if mA else None, lb, ub)
        qp.solve()
        info = qp.results.info
        status = info.status
        if status == self._px.QPSolverOutput.PROXQP_SOLVED:
            return "optimal", np.array(qp.results.x, dtype=np.float64), int(info.iter)
        name = str(status).rsplit(".", 1)[-1].lower()
        status_name = (
            "infeasible" if "infeasible" in name else "max_iter" if "max" in name else name
        )
        del self._qp[key]  # a failed workspace is rebuilt (no stale warm start)
        return status_name, None, int(info.iter)


class _Piqp(_DenseQP):
    name = "piqp"

    def __init__(self, tolerance: float, settings: Mapping[str, Any]) -> None:
        from ltv_lstm_mpc.solvers.tolerances import solver_options

        super().__init__(tolerance, settings)
        self.options = solver_options("piqp", tolerance, settings)
        import piqp

        self._piqp = piqp
        self._solver: dict[str, Any] = {}

    def solve(
        self,
        key: str,
        H: FloatArray,
        f: FloatArray,
        A: FloatArray,
        lo: FloatArray,
        up: FloatArray,
        lb: FloatArray,
        ub: FloatArray,
    ) -> tuple[str, FloatArray | None, int]:
        mA = A.shape[0]
        solver = self._solver.get(key)
        data: dict[str, Any] = {"P": H, "c": f, "x_l": lb, "x_u": ub}
        if mA:
            data.update(G=np.asfortranarray(A), h_l=lo, h_u=up)
        if solver is None:
            solver = self._piqp.DenseSolver()
            for name, value in self.options.items():
                setattr(solver.settings, name, value)
            solver.setup(**data)
            self._solver[key] = solver
        else:
            solver.update(**data)
        code = solver.solve()
        res = solver.result
        if code == self._piqp.PIQP_SOLVED:
            return "optimal", np.array(res.x, dtype=np.float64), int(res.info.iter)
        name = code.name.lower()
        status = "infeasible" if "infeasible" in name else "max_iter" if "max" in name else name
        return status, None, int(res.info.iter)


class _Osqp(_DenseQP):
    """OSQP with a fixed dense pattern (upper triangle of H, [I; A]) and ``update``."""

    name = "osqp"

    def __init__(self, tolerance: float, settings: Mapping[str, Any]) -> None:
        from ltv_lstm_mpc.solvers.tolerances import solver_options

        super().__init__(tolerance, settings)
        self.options = {"verbose": False, **solver_options("osqp", tolerance, settings)}
        import osqp

        self._osqp = osqp
        self._ws: dict[str, tuple[Any, Any, Any, Any, FloatArray, FloatArray, FloatArray]] = {}

    def solve(
        self,
        key: str,
        H: FloatArray,
        f: FloatArray,
        A: FloatArray,
        lo: FloatArray,
        up: FloatArray,
        lb: FloatArray,
        ub: FloatArray,
    ) -> tuple[str, FloatArray | None, int]:
        import scipy.sparse as sp

        nv, mA = f.shape[0], A.shape[0]
        ws = self._ws.get(key)
        if ws is None or ws[4].shape[0] != nv + mA:
            rows_p, cols_p = np.triu_indices(nv)
            order = np.lexsort((rows_p, cols_p))  # CSC order: by column, then row
            p_idx = (rows_p[order], cols_p[order])
            P = sp.csc_matrix((H[p_idx], p_idx), shape=(nv, nv))
            full = np.vstack([np.eye(nv), np.ones((mA, nv))])
            pattern = sp.csc_matrix(full)
            r, c = pattern.nonzero()
            order_a = np.lexsort((r, c))
            r, c = r[order_a], c[order_a]
            a_src = np.flatnonzero(r >= nv)  # positions of A entries in the data vector
            a_flat = (r[a_src] - nv) * nv + c[a_src]
            Ax = np.ones(r.size)
            Ax[a_src] = A.ravel()[a_flat]
            A_sp = sp.csc_matrix((Ax, (r, c)), shape=(nv + mA, nv))
            l_vec = np.concatenate([lb, lo])
            u_vec = np.concatenate([ub, up])
            solver = self._osqp.OSQP()
            solver.setup(P=P, q=f, A=A_sp, l=l_vec, u=u_vec, **self.options)
            ws = (solver, p_idx, a_src, a_flat, Ax, l_vec, u_vec)
            self._ws[key] = ws
        else:
            solver, p_idx, a_src, a_flat, Ax, l_vec, u_vec = ws
            Ax[a_src] = A.ravel()[a_flat]
            l_vec[:nv] = lb
            l_vec[nv:] = lo
            u_vec[:nv] = ub
            u_vec[nv:] = up
            solver.update(q=f, l=l_vec, u=u_vec, Px=H[p_idx], Ax=Ax)
        res = solver.solve(raise_error=False)  # warm start: OSQP keeps the last iterate
        val = int(res.info.status_val)
        if val in (1, 2):
            return "optimal", np.array(res.x, dtype=np.float64), int(res.info.iter)
        status = {3: "infeasible", 4: "unbounded", -2: "max_iter"}.get(val, "failed")
        return status, None, int(res.info.iter)


class _Qpsolvers(_DenseQP):
    """Any ``qpsolvers`` solver on the dense condensed QP (no persistent workspace)."""

    def __init__(self, solver: str, tolerance: float, settings: Mapping[str, Any]) -> None:
        import qpsolvers

        from ltv_lstm_mpc.solvers.tolerances import solver_options

        super().__init__(tolerance, settings)
        if solver not in qpsolvers.available_solvers:
            raise SolverNotFound(
                f"qpsolvers solver {solver!r} is not installed; "
                f"available: {sorted(qpsolvers.available_solvers)}"
            )
        self.name = f"qpsolvers:{solver}"
        self._solver = solver
        self._qps = qpsolvers
        self.options = solver_options(solver, tolerance, settings)

    def solve(
        self,
        key: str,
        H: FloatArray,
        f: FloatArray,
        A: FloatArray,
        lo: FloatArray,
        up: FloatArray,
        lb: FloatArray,
        ub: FloatArray,
    ) -> tuple[str, FloatArray | None, int]:
        G = np.vstack([A, -A]) if A.shape[0] else None
        h = np.concatenate([up, -lo]) if A.shape[0] else None
        problem = self._qps.Problem(H, f, G, h, None, None, lb, ub)
        sol = self._qps.solve_problem(problem, solver=self._solver, **self.options)
        if sol.found and sol.x is not None:
            return "optimal", np.asarray(sol.x, dtype=np.float64), 0
        return "failed", None, 0


def _make_qp(solver: str, tolerance: float, settings: Mapping[str, Any]) -> _DenseQP:
    classes: dict[str, type[_DenseQP]] = {
        "daqp": _Daqp,
        "quadprog": _Quadprog,
        "proxqp": _Proxqp,
        "piqp": _Piqp,
        "osqp": _Osqp,
    }
    if solver.startswith("qpsolvers:"):
        return _Qpsolvers(solver.split(":", 1)[1], tolerance, settings)
    if solver not in classes:
        raise SolverNotFound(
            f"fast-path solver {solver!r} is unknown; choose one of {FAST_SOLVERS} "
            "or 'qpsolvers:<name>'"
        )
    try:
        return classes[solver](tolerance, settings)
    except ImportError as error:
        raise SolverNotFound(
            f"solver {solver!r} is not installed ({error}); install the solvers with: "
            'pip install "ltv_lstm_mpc[solvers]"'
        ) from error


# =====================================================================================
# Fast robust MPC
# =====================================================================================
class FastRobustMPC:
    r"""The robust MPC of eq. (optimization), RTI on a condensed QP, split prepare/feedback.

    Same interface as :class:`~ltv_lstm_mpc.mpc.rti.RobustMPC` (``solve``, ``reset``,
    ``certification``, ``tightening``) plus :meth:`prepare` / :meth:`feedback`. The
    i = 0 output row and :math:`\alpha_k > 0` are checked first and the configured
    infeasibility policy (``"paper"``, ``"soft"``, ``"shift"``) is applied exactly as in
    RobustMPC; the terminal cones always get the
    :class:`~ltv_lstm_mpc.mpc.sparse.TerminalBoxReformulation` (recorded in
    ``MPCSolution.reformulation``). ``config.solver`` is ignored; ``sqp_iterations`` is
    1 (one real-time iteration).

    Parameters
    ----------
    model : LSTMModel
    config : MPCConfig, optional
    solver : str
        ``"daqp"`` (default), ``"quadprog"``, ``"proxqp"``, ``"piqp"`` (dense), ``"osqp"``
        (fixed pattern + ``update``), or ``"qpsolvers:<name>"``.
    certification : Certification, optional
    reuse_tol : float
        When the linearization start is within this distance (inf-norm) of the previous
        plan's predicted :math:`x_{1|k-1}`, the previous re-simulation is shifted instead
        of simulated again (the prediction *is* that trajectory).
    **settings
        Native solver settings (override the mapped ``config.tolerance``).

    Attributes
    ----------
    prepare_time, feedback_time, solver_time : float
        Wall times of the last :meth:`prepare`, :meth:`feedback` and solver calls, s.
    qp_iterations : int
        Solver iterations of the last feedback (all QPs it solved).
    """

    def __init__(
        self,
        model: LSTMModel,
        config: MPCConfig | None = None,
        *,
        solver: str = "daqp",
        certification: Certification | None = None,
        reuse_tol: float = 1e-9,
        **settings: Any,
    ) -> None:
        model.require_square()
        self.model = model
        self.config = config = config or MPCConfig()
        self.certification = certification or certify(model, config.certification_settings(model))
        self.tightening = ti = self.certification.tightening
        self.solver = solver
        self._qp = _make_qp(solver, config.tolerance, {**config.solver_settings, **settings})
        self.reuse_tol = float(reuse_tol)
        Q, R = config.weights(model)
        n, m, p, N = model.n, model.m, model.p, config.N
        n2 = 2 * n
        self.N = N
        self._sub = sub = FHOCPSubproblem(
            n=n, m=m, p=p, N=N, Q=Q, R=R, P_f=np.asarray(ti.P_f),
            W_y=model.W_y, b_y=model.b_y, u_max=config.u_max,
        )  # fmt: skip
        box = sub.reformulation
        self.reformulation: str = box.name
        self._unit_tau = np.asarray(box.unit_tau, dtype=np.float64)
        self.kernel = LSTMKernel(model)
        # ---- weights: ||L' (x_i - x_bar)||^2 per stage i = 1..N (stage N: terminal bound)
        term = np.concatenate([np.full(n, box.weight_c), np.full(n, box.weight_h)])
        self._diag_Q = bool(np.allclose(Q, np.diag(np.diag(Q))))
        if self._diag_Q:
            sw = np.tile(np.sqrt(np.diag(Q)), (N, 1))
            sw[N - 1] = np.sqrt(term)
            self._sw = sw[:, :, None]
        else:
            Lt = np.linalg.cholesky(Q).T
            self._Lt = np.tile(Lt, (N, 1, 1))
            self._Lt[N - 1] = np.diag(np.sqrt(term))
        self._R = R
        self._Rblk = np.kron(np.eye(N), R)
        self._Q = Q
        nu = N * m
        cols = n2 + nu
        self._cols = cols
        self._mA = (N - 1) * p + n2
        # ---- preallocated work arrays
        self._traj = self.kernel.trajectory(N)
        self._M = np.zeros((N + 1, n2, cols))
        self._M[0, :, :n2] = np.eye(n2)
        self._Maug = np.empty((N, n2, cols + 1))
        self._A_all = np.empty((self._mA, cols))
        self._lo0 = np.empty(self._mA)
        self._up0 = np.empty(self._mA)
        self._Maug_flat = self._Maug.reshape(N * n2, cols + 1)
        self._n_out = n_out = (N - 1) * p
        self._A_out_view = self._A_all[:n_out].reshape(N - 1, p, cols)
        self._lo0_view = self._lo0[:n_out].reshape(N - 1, p)
        self._up0_view = self._up0[:n_out].reshape(N - 1, p)
        self._W_y_T = np.ascontiguousarray(model.W_y.T)
        self._unit_half = np.repeat(self._unit_tau / np.sqrt(n), n)
        self._cand = np.empty((N, m))
        self._du_ref = np.empty((N, m))
        self._lb = np.empty(nu)
        self._ub = np.empty(nu)
        self._bounds_e = float("nan")
        self._bounds_y0: list[float] = []
        self._b_y_list = model.b_y.tolist()
        self._Q_scalar = float(Q[0, 0]) if np.array_equal(Q, Q[0, 0] * np.eye(n2)) else None
        self._R_scalar = float(R[0, 0]) if np.array_equal(R, R[0, 0] * np.eye(m)) else None
        P_f = np.asarray(ti.P_f)
        self._P_f = (float(P_f[0, 0]), float(P_f[0, 1] + P_f[1, 0]), float(P_f[1, 1]))
        self._plan = self.kernel.trajectory(N)
        self._plan_valid = False
        self._previous_u: FloatArray | None = None
        self._prepared = False
        self.prepare_time = self.feedback_time = self.solver_time = 0.0
        self.qp_iterations = 0

    # ----------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the previous plan (the next candidate is u_bar repeated)."""
        self._previous_u = None
        self._plan_valid = False
        self._prepared = False

    def candidate(self, u_bar: FloatArray) -> FloatArray:
        """Proof candidate: previous plan shifted by one with u_bar appended (SPEC 4)."""
        return shifted_candidate(self._previous_u, u_bar, self.N)

    def prepare(
        self,
        x_bar: ArrayLike,
        u_bar: ArrayLike,
        y0: ArrayLike,
        e_hat: float,
        *,
        x_pred: ArrayLike | None = None,
        warm: ArrayLike | None = None,
    ) -> None:
        r"""Linearize and condense before the estimate arrives (acados ``prepare``).

        Parameters
        ----------
        x_bar, u_bar, y0, e_hat
            As in :meth:`~ltv_lstm_mpc.mpc.rti.RobustMPC.solve`.
        x_pred : (2n,), optional
            Predicted :math:`\hat x_k` to linearize from; default the previous plan's
            :math:`x_{1|k-1}` (required at the first call).
        warm : (N, m), optional
            Inputs to linearize along (default: the proof candidate).
        """
        start = time.perf_counter()
        model, config, kernel = self.model, self.config, self.kernel
        n, m, p, N = model.n, model.m, model.p, self.N
        n2 = 2 * n
        self._x_bar = x_bar_a = np.asarray(x_bar, dtype=np.float64)
        self._u_bar = u_bar_a = np.asarray(u_bar, dtype=np.float64).reshape(m)
        self._bounds(np.asarray(y0, dtype=np.float64).reshape(p), float(e_hat))
        alpha = self._alpha
        cand = self._cand
        if warm is not None:
            cand[:] = np.asarray(warm, dtype=np.float64).reshape(N, m)
        elif self._previous_u is None:
            cand[:] = u_bar_a
        else:
            cand[:-1] = self._previous_u[1:]
            cand[-1] = u_bar_a
        traj, plan = self._traj, self._plan
        S = traj.S
        reuse = False
        if x_pred is None:
            if not self._plan_valid:
                raise InvalidValueError("the first prepare() needs x_pred (no previous plan)")
            reuse = warm is None
            x0 = plan.S[1, :n2]
        else:
            x0 = np.asarray(x_pred, dtype=np.float64)
            if warm is None and self._plan_valid:
                reuse = float(np.abs(x0 - plan.S[1, :n2]).max()) <= self.reuse_tol
        if reuse:
            # The shifted candidate from x_{1|k-1} is the re-simulated plan shifted by one.
            S[:N] = plan.S[1:]
            traj.T[: N - 1] = plan.T[1:]
            traj.TC[: N - 1] = plan.TC[1:]
            S[N - 1, n2 : n2 + m] = cand[N - 1]
            kernel.rollout(traj, N - 1, N)
        else:
            S[0, :n2] = x0
            S[:N, n2 : n2 + m] = cand
            kernel.rollout(traj, 0, N)
        kernel.jacobians(traj)
        # ---- condensing: M_{i+1} = A_i M_i + B_i e_i, columns [dx0 | du]
        M, J = self._M, traj.J
        matmul = np.matmul
        for i in range(N):
            matmul(J[i, :, :n2], M[i], out=M[i + 1])
            M[i + 1, :, n2 + i * m : n2 + (i + 1) * m] = J[i, :, n2:]
        Maug = self._Maug
        if self._diag_Q:
            np.multiply(self._sw, M[1:], out=Maug[:, :, :-1])
            np.subtract(S[1:, :n2], x_bar_a, out=Maug[:, :, -1])
            Maug[:, :, -1] *= self._sw[:, :, 0]
        else:
            matmul(self._Lt, M[1:], out=Maug[:, :, :-1])
            matmul(self._Lt, (S[1:, :n2] - x_bar_a)[:, :, None], out=Maug[:, :, -1:])
        flat = self._Maug_flat
        gram = flat.T @ flat
        self._H = gram[n2:-1, n2:-1] + self._Rblk
        self._F = gram[n2:-1, :n2].copy()
        du_ref = self._du_ref
        np.subtract(cand, u_bar_a, out=du_ref)
        self._g0 = gram[n2:-1, -1] + self._Rblk @ du_ref.reshape(-1)
        # ---- rows: tightened outputs i = 1..N-1, then the terminal box on x_N
        A_all, lo0, up0 = self._A_all, self._lo0, self._up0
        n_out = self._n_out
        if N > 1:
            matmul(model.W_y, M[1:N, n:n2], out=self._A_out_view)
            y_lin = S[1:N, n:n2] @ self._W_y_T
            y_lin += model.b_y
            np.subtract(self._lower_tail, y_lin, out=self._lo0_view)
            np.subtract(self._upper_tail, y_lin, out=self._up0_view)
        A_all[n_out:] = M[N]
        half = self._unit_half * max(alpha, 0.0)
        centre = x_bar_a - S[N, :n2]
        np.subtract(centre, half, out=lo0[n_out:])
        np.add(centre, half, out=up0[n_out:])
        self._A = A_all[:, n2:].copy()
        self._E = A_all[:, :n2].copy()
        flat_cand = cand.reshape(-1)
        np.subtract(-config.u_max, flat_cand, out=self._lb)
        np.subtract(config.u_max, flat_cand, out=self._ub)
        self._prepared = True
        self.prepare_time = time.perf_counter() - start

    def _bounds(self, y0: FloatArray, e_hat: float) -> None:
        """Tightened bounds and alpha_k, eq. (optimization_constraint_yub)/(def_alpha), cached.

        The same formulas as :meth:`TighteningCertificate.output_bounds` and
        :meth:`TighteningCertificate.alpha`, evaluated only when e_hat or y0 change.
        """
        y0_list = y0.tolist()
        if e_hat == self._bounds_e and y0_list == self._bounds_y0:
            return
        ti = self.tightening
        if e_hat != self._bounds_e:
            self._lower, self._upper = ti.output_bounds(e_hat)
            self._lower_tail = self._lower[1:]
            self._upper_tail = self._upper[1:]
            self._row0 = (self._lower[0].tolist(), self._upper[0].tolist())
            margin = 2.0 * ti.d_max + ti.a[ti.N] * ti.e_tilde(e_hat) + ti.b[ti.N]
            self._alpha_terms = list(
                zip(
                    ((ti.y_max - margin) / ti.kappa).tolist(),
                    ((ti.y_min + margin) / ti.kappa).tolist(),
                    (1.0 / ti.kappa).tolist(),
                    strict=True,
                )
            )
        # eq. (def_alpha): min_j kappa_j^-1 min(y_max - y0 - margin, y0 - y_min - margin)
        self._alpha = min(
            min(hi - y * ik, y * ik - lo)
            for y, (hi, lo, ik) in zip(y0_list, self._alpha_terms, strict=True)
        )
        self._y0 = y0
        self._bounds_e, self._bounds_y0 = e_hat, y0_list

    # ----------------------------------------------------------------------------------
    def _solve_policy(
        self, name: str, f: FloatArray, lo: FloatArray, up: FloatArray
    ) -> tuple[str, FloatArray | None, int]:
        """One QP of the given kind; returns (status, du, iterations)."""
        H, A, lb, ub = self._H, self._A, self._lb, self._ub
        if name == "nominal":
            return self._qp.solve("nominal", H, f, A, lo, up, lb, ub)
        if name == "paper":  # drop output and terminal rows (paper, Fig. 5)
            return self._qp.solve("paper", H, f, A[:0], lo[:0], up[:0], lb, ub)
        # "soft": L1 slacks on the output rows; terminal box with max(alpha, 0) (as the
        # TerminalBoxReformulation does for the soft problem: no QP terminal slack).
        N, p, nu = self.N, self.model.p, H.shape[0]
        ns = (N - 1) * p
        reg = 1e-9 * float(np.max(np.diag(H)))  # slacks enter linearly: tiny regularization
        Hs = np.zeros((nu + ns, nu + ns))
        Hs[:nu, :nu] = H
        Hs[nu:, nu:] = reg * np.eye(ns)
        fs = np.concatenate([f, np.full(ns, 0.5 * self.config.soft_penalty)])
        rows = []
        low, high = [], []
        A_out, A_T = A[:ns], A[ns:]
        eye = np.eye(ns)
        rows.append(np.hstack([A_out, eye]))  # A du + s >= lo
        low.append(lo[:ns])
        high.append(np.full(ns, np.inf))
        rows.append(np.hstack([A_out, -eye]))  # A du - s <= up
        low.append(np.full(ns, -np.inf))
        high.append(up[:ns])
        rows.append(np.hstack([A_T, np.zeros((A_T.shape[0], ns))]))
        low.append(lo[ns:])
        high.append(up[ns:])
        As = np.ascontiguousarray(np.vstack(rows))
        lbs = np.concatenate([lb, np.zeros(ns)])
        ubs = np.concatenate([ub, np.full(ns, np.inf)])
        status, z, iters = self._qp.solve(
            "soft", Hs, fs, As, np.concatenate(low), np.concatenate(high), lbs, ubs
        )
        return status, None if z is None else z[:nu], iters

    def feedback(self, x_hat: ArrayLike) -> MPCSolution:
        r"""Insert :math:`\hat x_k`, solve the prepared QP, re-simulate (acados ``feedback``).

        Returns
        -------
        MPCSolution
            ``solve_time`` is prepare + feedback time; ``solver_time`` the QP calls.
        """
        start = time.perf_counter()
        if not self._prepared:
            raise LtvMpcError("feedback() needs a prepare() first")
        self._prepared = False
        model, config = self.model, self.config
        n, N, m = model.n, self.N, model.m
        n2 = 2 * n
        x_hat_a = np.asarray(x_hat, dtype=np.float64)
        lower, upper, alpha = self._lower, self._upper, self._alpha
        y_first = [
            yf + by
            for yf, by in zip((self._W_y_T.T @ x_hat_a[n:]).tolist(), self._b_y_list, strict=True)
        ]
        status = precheck_status(y_first, *self._row0, alpha)
        S = self._traj.S
        dx0 = x_hat_a - S[0, :n2]
        f = self._F @ dx0
        f += self._g0
        shift = self._E @ dx0
        lo = self._lo0 - shift
        up = self._up0 - shift
        solver_time = 0.0
        iterations = 0
        du: FloatArray | None = None
        if not status:
            t0 = time.perf_counter()
            status, du, iterations = self._solve_policy("nominal", f, lo, up)
            solver_time += time.perf_counter() - t0
        feasible = status == "optimal"
        policy = "nominal"
        if not feasible:
            policy = config.infeasibility_policy
            du = None
            if policy != "shift":
                t0 = time.perf_counter()
                _, du, fb_iters = self._solve_policy(policy, f, lo, up)
                solver_time += time.perf_counter() - t0
                iterations += fb_iters
                if du is None:
                    policy = f"{policy}+shift"
        cand = self._cand
        P = self._plan.S
        u_plan = P[:N, n2 : n2 + m]
        if du is None:
            u_plan[:] = cand
            x_linear = np.full((N + 1, n2), np.nan)
            step = 0.0
        else:
            np.add(cand, du.reshape(N, m), out=u_plan)
            np.minimum(u_plan, config.u_max, out=u_plan)
            np.maximum(u_plan, -config.u_max, out=u_plan)
            x_linear = self._M @ np.concatenate([dx0, du])
            x_linear += S[:, :n2]
            step = float(np.abs(du).max())
        # ---- re-simulate the plan on the true LSTM (nonlinear residuals)
        P[0, :n2] = x_hat_a
        self.kernel.rollout(self._plan, 0, N)
        self._plan_valid = True
        u_out = u_plan.copy()
        self._previous_u = u_out
        x_plan = P[:, :n2].copy()
        y_plan = x_plan[:N, n:] @ self._W_y_T
        y_plan += model.b_y
        dx = x_plan - self._x_bar
        tc2 = float(dx[N, :n] @ dx[N, :n])
        th2 = float(dx[N, n:] @ dx[N, n:])
        p11, p12, p22 = self._P_f
        terminal = p11 * tc2 + p12 * np.sqrt(tc2 * th2) + p22 * th2
        du_bar = u_out - self._u_bar
        dxs = dx[:N]
        if self._Q_scalar is not None:
            stage = self._Q_scalar * float(np.vdot(dxs, dxs))
        else:
            stage = float(np.einsum("ki,ij,kj->", dxs, self._Q, dxs))
        if self._R_scalar is not None:
            stage += self._R_scalar * float(np.vdot(du_bar, du_bar))
        else:
            stage += float(np.einsum("ki,ij,kj->", du_bar, self._R, du_bar))
        violation = max(0.0, float((lower - y_plan).max()), float((y_plan - upper).max()))
        residuals = {
            "output_violation": violation,
            "terminal_residual": float(np.sqrt(terminal)) - alpha,
            "linearization_gap": float(np.abs(x_plan - x_linear).max())
            if du is not None
            else float("nan"),
        }
        self.solver_time = solver_time
        self.qp_iterations = iterations
        self.feedback_time = time.perf_counter() - start
        return MPCSolution(
            u=u_out,
            x=x_plan,
            x_linear=x_linear,
            status=status,
            feasible=feasible,
            policy=policy,
            solve_time=self.prepare_time + self.feedback_time,
            solver_time=solver_time,
            iterations=1,
            sqp_step=step,
            alpha=alpha,
            cost=stage + terminal,
            residuals=residuals,
            reformulation=self.reformulation,
            solver_iterations=iterations,
        )

    def solve(
        self,
        x_hat: ArrayLike,
        x_bar: ArrayLike,
        u_bar: ArrayLike,
        y0: ArrayLike,
        e_hat: float,
        *,
        warm: ArrayLike | None = None,
    ) -> MPCSolution:
        r"""``prepare`` from :math:`\hat x_k` then ``feedback`` (RobustMPC's interface).

        Parameters are those of :meth:`~ltv_lstm_mpc.mpc.rti.RobustMPC.solve`.
        """
        model = self.model
        n2, m, p = 2 * model.n, model.m, model.p
        x_hat_a = checked_vector("x_hat", x_hat, n2)
        e_hat = float(e_hat)
        if not np.isfinite(e_hat) or e_hat < 0:
            raise InvalidValueError(f"e_hat must be a finite nonnegative number, got {e_hat}")
        if warm is not None and np.shape(warm) != (self.N, m):
            raise DimensionError(f"warm has shape {np.shape(warm)}, expected ({self.N}, {m})")
        self.prepare(
            checked_vector("x_bar", x_bar, n2),
            checked_vector("u_bar", u_bar, m),
            checked_vector("y0", y0, p),
            e_hat,
            x_pred=x_hat_a,
            warm=warm,
        )
        return self.feedback(x_hat_a)


# =====================================================================================
# Fused controller step
# =====================================================================================
class FastOffsetFreeController(OffsetFreeController):
    r"""Fig. 1 in one lean step: observer, reference calculator and the fast RTI step.

    Behaves as :class:`~ltv_lstm_mpc.loop.controller.OffsetFreeController` with
    ``mpc=FastRobustMPC(...)`` (same timing convention, rate limiter, records and
    :math:`\hat e_{o,k}` update eq. eo_evolution) but with the observer eq.
    (lstm_observer) on the lean kernel and the warm-started
    :class:`FastReferenceCalculator`. The first step initializes through the regular
    (slow) path.

    Parameters
    ----------
    model : LSTMModel
    config : MPCConfig, optional
    solver : str
        Fast-path solver (see :class:`FastRobustMPC`).
    setpoint_rate_limit : float, optional
    mpc : FastRobustMPC, optional
        Prebuilt fast MPC (default ``FastRobustMPC(model, config, solver=solver)``).
    """

    def __init__(
        self,
        model: LSTMModel,
        config: MPCConfig | None = None,
        *,
        solver: str = "daqp",
        setpoint_rate_limit: float | None = None,
        mpc: FastRobustMPC | None = None,
    ) -> None:
        config = config or MPCConfig()
        self.fast_mpc = mpc if mpc is not None else FastRobustMPC(model, config, solver=solver)
        self.fast_reference = FastReferenceCalculator(model, u_max=config.u_max)
        super().__init__(
            model,
            config,
            setpoint_rate_limit=setpoint_rate_limit,
            mpc=self.fast_mpc,
        )
        self._kernel = LSTMKernel(model)
        n, m = model.n, model.m
        self._obs = self._kernel.trajectory(1)
        gains = self.observer.gains
        L_gates = np.vstack([gains.L_f, gains.L_i, gains.L_o, np.zeros((n, model.p))])
        self._L_gates = None if not np.any(L_gates) else L_gates
        self._W_y, self._b_y = model.W_y, model.b_y
        self._y_buf = np.empty(model.p)
        norm = model.normalization
        assert norm is not None
        self._y_min, self._y_scale = norm.y_phi_min, norm.y_scale
        self._u_min, self._u_scale = norm.u_phi_min, norm.u_scale
        del n, m

    def reset(self) -> None:
        """Back to the uninitialized state (the next step initializes the observer)."""
        super().reset()
        if hasattr(self, "fast_reference"):
            self.fast_reference.reset()

    def _observer_step(self, y: FloatArray, u: FloatArray) -> None:
        """eq. (lstm_observer) on the lean kernel (same math as Observer.step)."""
        obs = self.observer
        n2 = 2 * self.model.n
        x_hat, d_hat = obs.x_hat, obs.d_hat
        innovation = self._W_y @ x_hat[n2 // 2 :]
        innovation += self._b_y
        innovation += d_hat
        np.subtract(y, innovation, out=innovation)
        S = self._obs.S
        S[0, :n2] = x_hat
        S[0, n2:-1] = u
        extra = None if self._L_gates is None else self._L_gates @ innovation
        self._kernel.rollout(self._obs, 0, 1, extra)
        obs.x_hat = S[1, :n2].copy()
        d_new = obs.gains.L_d @ innovation
        d_new += d_hat
        np.minimum(d_new, obs.d_max, out=d_new)
        np.maximum(d_new, -obs.d_max, out=d_new)
        obs.d_hat = d_new

    # Hooks of OffsetFreeController.step (same loop, same records), lean versions.
    def _normalize(self, y_phi: ArrayLike, y0_phi: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Normalized measurement and set-point without the generic helpers' overhead."""
        p = self.model.p
        y_arr = np.asarray(y_phi, dtype=np.float64)
        y0_arr = np.asarray(y0_phi, dtype=np.float64)
        if y_arr.size != p or y0_arr.size != p:
            raise InvalidValueError(f"y_phi and y0_phi must have {p} entries")
        y = (y_arr.reshape(p) - self._y_min) / self._y_scale - 1.0
        y0_target = (y0_arr.reshape(p) - self._y_min) / self._y_scale - 1.0
        if not math.isfinite(float(y.sum() + y0_target.sum())):
            raise InvalidValueError(f"y_phi and y0_phi must be finite, got {y_phi!r}, {y0_phi!r}")
        return y, y0_target

    def _solve_reference(self, y0: FloatArray, d_hat: FloatArray) -> ReferenceSolution:
        """Chord-Newton eq. (reference_calculation), falling back to the full solver."""
        return self.fast_reference.solve(y0, d_hat)

    def _solve_mpc(
        self, x_hat: FloatArray, reference: ReferenceSolution, y0: FloatArray
    ) -> MPCSolution:
        """prepare (candidate, linearization, condensing) then feedback (insert x_hat, solve)."""
        mpc = self.fast_mpc
        mpc.prepare(reference.x_bar, reference.u_bar, y0, self.e_hat, x_pred=x_hat)
        return mpc.feedback(x_hat)

    def _update_observer(self, y: FloatArray, u: FloatArray) -> None:
        """eq. (lstm_observer) on the lean kernel."""
        self._observer_step(y, u)

    def _denormalize_u(self, u: FloatArray) -> FloatArray:
        """Physical input from the normalized one."""
        return np.asarray((u + 1.0) * self._u_scale + self._u_min, dtype=np.float64)
