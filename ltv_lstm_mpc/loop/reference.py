r"""Reference calculator, eq. (reference_calculation).

Given the set-point :math:`y^0` and the disturbance estimate :math:`\hat d`, find the
equilibrium :math:`(\bar x, \bar u)` with

.. math::

    \bar x = f(\bar x, \bar u), \qquad y^0 = g(\bar x) + \hat d

by Newton's method on the :math:`(2n + m)` square system (m = p, Assumption 1) with the
analytic Jacobian of eq. (jacobian), warm-started from the previous solution.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

# K_bar of Lemma 5 is a certificate number: its home is certificates/reference_gain.py
# (re-exported here, where it was first defined).
from ltv_lstm_mpc.certificates.reference_gain import KBarEstimate, estimate_K_bar
from ltv_lstm_mpc.deferred_state import Deferred, DeferredSetting, DeferredState, settle
from ltv_lstm_mpc.exceptions import UnreachableSetpointError
from ltv_lstm_mpc.loop.compiled_reference import (
    CHORD_CONVERGED,
    CHORD_FACTORIZATIONS,
    CHORD_ITERATIONS,
    CHORD_JINV_VALID,
    CHORD_REFRESH_CONTRACTION,
    U_MARGIN,
    chord_newton,
    new_chord_workspace,
    new_restart_workspace,
    newton_restarts,
)
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.validation import (
    expect_bool,
    expect_int,
    expect_real,
    real_vector,
)

__all__ = [
    "ChordState",
    "KBarEstimate",
    "ReferenceCalculator",
    "ReferenceSolution",
    "WarmStart",
    "estimate_K_bar",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class ChordState:
    """The compiled warm path's parts (:meth:`ReferenceCalculator.chord_state`).

    Attributes
    ----------
    workspace : ChordWorkspace
        :data:`~ltv_lstm_mpc.loop.compiled_reference.ChordWorkspace` of
        :func:`~ltv_lstm_mpc.loop.compiled_reference.chord_newton`.
    jinv : ndarray (2n + m, 2n + m)
        The inverse Jacobian it keeps between steps (written in place).
    restart : RestartWorkspace
        :data:`~ltv_lstm_mpc.loop.compiled_reference.RestartWorkspace` of the damped Newton
        with restarts where the warm path fails
        (:func:`~ltv_lstm_mpc.loop.compiled_reference.newton_restarts`).
    """

    workspace: Any
    jinv: FloatArray
    restart: Any = None


@dataclass(frozen=True, slots=True)
class WarmStart:
    """Where the warm path starts (:meth:`ReferenceCalculator.warm_start`).

    Attributes
    ----------
    last_z : ndarray (2n + m,)
        The last solution :math:`[\\bar x; \\bar u]`.
    last_target : ndarray (p,) or None
        Its target :math:`y^0 - \\hat d`.
    jinv_valid : int
        1 when the kept inverse Jacobian is valid, else 0.
    """

    last_z: FloatArray
    last_target: FloatArray | None
    jinv_valid: int


@dataclass(slots=True)  # one per control step: not frozen (2 us less to build)
class ReferenceSolution:
    r"""Result of eq. (reference_calculation).

    Attributes
    ----------
    x_bar : ndarray, shape (2n,)
        State set-point :math:`\bar x = [\bar c; \bar h]`.
    u_bar : ndarray, shape (m,)
        Input set-point :math:`\bar u`.
    residual : float
        :math:`\|F(\bar x, \bar u)\|_\infty` of the stacked equations.
    jacobian_condition : float
        2-norm condition number of the Jacobian eq. (jacobian) at the solution
        (Assumption 4 needs it finite); NaN when the warm chord path answered (not
        computed there, for speed).
    u_admissible : bool
        Whether :math:`\bar u \in \mathcal{U}` (:math:`\|\bar u\|_\infty \le u_{max}`).
    converged : bool
        Whether Newton reached the tolerance.
    iterations : int
        Newton iterations used (all restarts included).
    """

    x_bar: FloatArray
    u_bar: FloatArray
    residual: float
    jacobian_condition: float
    u_admissible: bool
    converged: bool
    iterations: int

    @property
    def ok(self) -> bool:
        """Converged with an admissible input."""
        return self.converged and self.u_admissible


class ReferenceCalculator(DeferredState):
    r"""Solve eq. (reference_calculation) by Newton's method with warm start.

    Parameters
    ----------
    model : LSTMModel
        Needs m = p (Assumption 1).
    u_max : float
        Input bound of :math:`\mathcal{U}` (normalized).
    tol : float
        Convergence tolerance on :math:`\|F\|_\infty`.
    max_iter : int
        Newton iterations per start.
    strict : bool
        If True (default), :meth:`solve` raises :class:`UnreachableSetpointError` when
        Newton fails or :math:`\bar u \notin \mathcal{U}`; if False it returns the
        solution with ``converged`` / ``u_admissible`` flags for the caller to act on.
    grid_points : int
        Inputs per channel of the equilibrium grid used for cold starts and for the
        reachable-output range in error messages.
    restarts : int
        For MIMO models, how many grid equilibria (closest in output) the damped Newton
        also starts from when the previous solution does not lead to an admissible one.

    Notes
    -----
    A cold start picks the grid equilibrium whose output is closest to
    :math:`y^0 - \hat d`; later calls start from the previous solution. When that start
    does not reach an admissible equilibrium (:math:`\bar u \in \mathcal U`), the other
    starts are tried and the admissible solution closest to the previous one is returned;
    strict mode raises only when none of them is admissible.
    """

    # The warm start: the last solution [x_bar; u_bar], its target y0 - d_hat and the kept
    # inverse Jacobian (a one-call step may leave them deferred: ltv_lstm_mpc.deferred_state).
    _last_z = Deferred[FloatArray | None]()
    _last_target = Deferred[FloatArray | None]()
    _Jinv = Deferred[FloatArray | None]()
    # Settings the controller's one-call workspace holds (assigning one ends a deferral).
    tol = DeferredSetting[float]()
    max_iter = DeferredSetting[int]()
    jump = DeferredSetting[float]()

    def __init__(
        self,
        model: LSTMModel,
        *,
        u_max: float = 1.0,
        tol: float = 1e-12,
        max_iter: int = 50,
        strict: bool = True,
        grid_points: int = 21,
        restarts: int = 4,
    ) -> None:
        model = require_model(model)
        model.require_square()
        expect_real("u_max", u_max, low=0.0, low_open=True)
        expect_real("tol", tol, low=0.0, low_open=True)
        expect_int("max_iter", max_iter, minimum=1)
        expect_bool("strict", strict)
        expect_int("grid_points", grid_points, minimum=1)
        expect_int("restarts", restarts, minimum=0)
        self.model = model
        self.u_max = float(u_max)
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.strict = strict
        #: Grid start points tried by the damped Newton for MIMO models (1 for SISO).
        self.restarts = max(1, int(restarts))
        #: A warm-path step larger than this (inf-norm of [x_bar; u_bar], normalized) on a
        #: MIMO model is checked against the restarts (another branch of a fold?).
        self.jump = 0.05
        n2, m = 2 * model.n, model.m
        self._eye = np.eye(n2)
        self._jacobian = np.zeros((n2 + m, n2 + m))
        self._jacobian[n2:, model.n : n2] = model.W_y
        self._last_z = None  # previous solution [x_bar; u_bar]
        # Warm path (chord Newton on the model's kernel): _chord_numpy or its compiled twin.
        self._traj = model.kernel.trajectory(1)
        self._z_view = self._traj.S[0, : n2 + m]
        self._chord_jacobian = self._jacobian.copy()
        self._chord_F = np.empty(n2 + m)
        self._diag = np.arange(n2)
        self._Jinv = None
        self._last_target = None
        per_channel = max(2, round(grid_points ** (1.0 / m))) if m > 1 else grid_points
        axes = [np.linspace(-self.u_max, self.u_max, per_channel)] * m
        grid_u = np.array(list(itertools.product(*axes)), dtype=np.float64)
        grid_x = np.empty((grid_u.shape[0], n2))
        x_start = None
        for k, u in enumerate(grid_u):
            grid_x[k] = model.equilibrium(u, x0=x_start)
            x_start = grid_x[k]
        self._grid_u = grid_u
        self._grid_x = grid_x
        self._grid_y = model.output(grid_x)
        self._compiled = model.kernel.compiled  # the warm path in one numba call
        #: The chord-Newton warm path, chosen once: compiled twin or numpy reference.
        self._chord = self._chord_numpy
        self._chord_state = np.zeros(4, dtype=np.int64)
        self._Jinv_buffer = np.zeros((n2 + m, n2 + m))
        self._W_y = np.ascontiguousarray(model.W_y)
        self._b_y = np.ascontiguousarray(model.b_y)
        self._chord_workspace: Any = None  # the compiled warm path's buffers
        self._chord_parts: ChordState | None = None  # (chord_state)
        #: (restarts, u_max) the compiled restart loop's workspace holds (``solve_arrays``
        #: takes the numpy loop where either was assigned since); None without it.
        self._restart_settings: tuple[int, float] | None = None
        if self._compiled:
            self._chord = self._chord_compiled
            traj, kernel = self._traj, model.kernel
            self._chord_workspace = new_chord_workspace(
                WU=kernel.WU,
                WU_raw=kernel.WU_raw,
                W_y=self._W_y,
                b_y=self._b_y,
                S=traj.S,
                T=traj.T,
                TC=traj.TC,
                J=traj.J,
                Jinv=self._Jinv_buffer,
                state=self._chord_state,
                F=self._chord_F,
                jacobian=self._chord_jacobian,
            )
            self._chord_parts = ChordState(
                self._chord_workspace, self._Jinv_buffer, self._restart_workspace()
            )
            self._restart_settings = (self.restarts, self.u_max)
        #: Chord-Jacobian factorizations / fallbacks from the warm path to damped Newton.
        self.counts = {"factorizations": 0, "fallbacks": 0}

    def _restart_workspace(self) -> Any:
        """The compiled twin's buffers of the damped Newton with restarts (its grid, its
        scratch): :func:`~ltv_lstm_mpc.loop.compiled_reference.newton_restarts`."""
        size = self._jacobian.shape[0]
        return new_restart_workspace(
            grid_x=np.ascontiguousarray(self._grid_x), grid_u=np.ascontiguousarray(self._grid_u),
            grid_y=np.ascontiguousarray(self._grid_y), restarts=int(self.restarts),
            u_max=float(self.u_max), jacobian=np.zeros((size, size)), z=np.zeros(size),
            trial=np.zeros(size), best=np.zeros(size), distance=np.zeros(self._grid_y.shape[0]),
            step=np.zeros(size), pivots=np.zeros(size, dtype=np.int64),
        )  # fmt: skip

    @property
    def reachable_output_range(self) -> tuple[FloatArray, FloatArray]:
        r"""Min and max equilibrium output :math:`g(x^*(u))` over the grid of inputs."""
        return self._grid_y.min(axis=0), self._grid_y.max(axis=0)

    def reset(self) -> None:
        """Forget the warm start."""
        self._last_z = None
        self._Jinv = None
        self._last_target = None

    # ---------------------------------------------------------------- warm path
    def _chord_residual(self, z: FloatArray, target: FloatArray) -> float:
        r""":math:`\|F(z)\|_\infty` on the kernel; leaves F and the gates at z in buffers."""
        model, n2 = self.model, 2 * self.model.n
        self._z_view[:] = z
        model.kernel.rollout(self._traj, 0, 1)
        F = self._chord_F
        np.subtract(self._traj.S[1, :n2], z[:n2], out=F[:n2])
        np.dot(model.W_y, z[model.n : n2], out=F[n2:])
        F[n2:] += model.b_y
        F[n2:] -= target
        return float(np.abs(F).max())

    def _chord_factorize(self) -> bool:
        """Inverse Jacobian eq. (jacobian) at the point of the last residual evaluation;
        False (and no inverse) where it is singular."""
        self.model.kernel.jacobians(self._traj)
        n2 = 2 * self.model.n
        jac = self._chord_jacobian
        jac[:n2] = self._traj.J[0]
        jac[self._diag, self._diag] -= 1.0
        try:
            self._Jinv = np.linalg.inv(jac)
        except np.linalg.LinAlgError:
            self._Jinv = None
            return False
        self.counts["factorizations"] += 1
        return True

    def _chord_compiled(self, target: FloatArray) -> tuple[FloatArray, float, int, bool]:
        """:meth:`_chord_numpy` in one numba call (``loop/compiled_reference.py``)."""
        state = self._chord_state
        state[CHORD_JINV_VALID] = 1 if self._Jinv is not None else 0
        step = target - self._last_target if self._last_target is not None else target * 0.0
        z = np.empty_like(self._last_z)
        norm = chord_newton(
            self._chord_workspace, self._last_z, target, step, self.tol, self.max_iter, z
        )
        self.adopt_chord_state(int(state[CHORD_JINV_VALID]), int(state[CHORD_FACTORIZATIONS]))
        return z, float(norm), int(state[CHORD_ITERATIONS]), bool(state[CHORD_CONVERGED])

    def chord_state(self) -> ChordState | None:
        """What a compiled step engine runs the warm path with: the compiled chord Newton's
        workspace and the inverse Jacobian buffer it keeps (None on the numpy kernel)."""
        return self._chord_parts

    @property
    def last_z(self) -> FloatArray | None:
        """The last solution :math:`[\\bar x; \\bar u]` (None: none yet)."""
        return self._last_z

    @property
    def last_target(self) -> FloatArray | None:
        """The target :math:`y^0 - \\hat d` of the last solution (None: none yet)."""
        return self._last_target

    @property
    def jinv_valid(self) -> int:
        """1 when the warm path's kept inverse Jacobian is valid, else 0."""
        return 0 if self._Jinv is None else 1

    def warm_start(self) -> WarmStart | None:
        """The warm path's start: the last solution :math:`[\\bar x; \\bar u]`, its target
        :math:`y^0 - \\hat d` (None: none yet) and whether the kept inverse Jacobian is valid;
        None before any solution."""
        last_z = self._last_z
        if last_z is None:
            return None
        return WarmStart(last_z, self._last_target, 0 if self._Jinv is None else 1)

    def settle_warm_start(
        self, last_z: FloatArray, last_target: FloatArray, inverse_valid: int
    ) -> None:
        """Take the warm start a compiled step left in its record row (views, never written
        again) and its inverse Jacobian's validity, ending a deferral
        (:mod:`ltv_lstm_mpc.deferred_state`)."""
        jinv = self._Jinv_buffer if inverse_valid == 1 else None
        settle(self, {"_last_z": last_z, "_last_target": last_target, "_Jinv": jinv})

    def adopt_chord_state(self, inverse_valid: int, factorizations: int) -> None:
        """After a compiled chord Newton (here or in the controller's one-call step): keep
        the inverse Jacobian it left in the workspace if it is valid, count its
        factorizations."""
        self._Jinv = self._Jinv_buffer if inverse_valid == 1 else None
        self.counts["factorizations"] += factorizations

    def _chord_numpy(self, target: FloatArray) -> tuple[FloatArray, float, int, bool]:
        r"""Warm-started chord Newton from the previous solution: (z, residual, iterations, ok).

        The equilibrium moves little between samples, so the inverse Jacobian is kept from
        the last factorization (one residual evaluation per iteration) and refreshed only
        when an iteration reduces the residual by less than
        :data:`~ltv_lstm_mpc.loop.compiled_reference.CHORD_REFRESH_CONTRACTION` (0.1: a
        refresh costs as much as about 15 iterations); the implicit-function
        predictor of Lemma 5 moves the start with the target. At steady state the call is
        one residual check. ``ok`` is False when an iteration with a fresh Jacobian does not
        decrease the residual: the caller then runs the damped Newton with restarts.
        """
        assert self._last_z is not None
        n2 = 2 * self.model.n
        z = self._last_z
        if self._Jinv is not None and self._last_target is not None:
            z = z + self._Jinv[:, n2:] @ (target - self._last_target)
        norm = self._chord_residual(z, target)
        iterations, fresh = 0, False
        while norm >= self.tol and iterations < self.max_iter:
            if self._Jinv is None:
                if not self._chord_factorize():  # singular: no chord (the Newton runs)
                    break
                fresh = True
            assert self._Jinv is not None
            z_new = z - self._Jinv @ self._chord_F
            iterations += 1
            norm_new = self._chord_residual(z_new, target)
            if not norm_new < norm:
                if fresh:
                    break
                self._Jinv = None
                norm = self._chord_residual(z, target)  # restore the buffers at z
                continue
            if norm_new > CHORD_REFRESH_CONTRACTION * norm:
                self._Jinv = None  # slow contraction: refactorize at z_new
            z, norm, fresh = z_new, norm_new, False
        return z, norm, iterations, norm < self.tol

    def _residual(
        self, z: FloatArray, target: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        n2 = 2 * self.model.n
        x, u = z[:n2], z[n2:]
        x_next, A, B = self.model.step_and_jacobians_arrays(x, u)
        F = np.concatenate([x_next - x, self.model.output(x) - target])
        return F, A, B

    def _newton(
        self, z: FloatArray, target: FloatArray
    ) -> tuple[FloatArray, float, int, bool, FloatArray, FloatArray]:
        """Damped Newton from z: (z, residual, iterations, converged, A, B at z)."""
        n2 = 2 * self.model.n
        J = self._jacobian
        F, A, B = self._residual(z, target)
        norm = float(np.max(np.abs(F)))
        for iteration in range(1, self.max_iter + 1):
            if norm < self.tol:
                return z, norm, iteration - 1, True, A, B
            J[:n2, :n2] = A - self._eye
            J[:n2, n2:] = B
            try:
                step = np.linalg.solve(J, F)
            except np.linalg.LinAlgError:
                return z, norm, iteration, False, A, B
            # Backtracking on the residual inf-norm (damped Newton).
            t = 1.0
            for _ in range(30):
                z_trial = z - t * step
                F_trial, A_trial, B_trial = self._residual(z_trial, target)
                norm_trial = float(np.max(np.abs(F_trial)))
                if norm_trial < norm or norm_trial < self.tol:
                    break
                t *= 0.5
            else:
                return z, norm, iteration, False, A, B
            z, F, A, B, norm = z_trial, F_trial, A_trial, B_trial, norm_trial
        return z, norm, self.max_iter, norm < self.tol, A, B

    def solve(
        self,
        y0: ArrayLike,
        d_hat: ArrayLike,
        *,
        warm: tuple[ArrayLike, ArrayLike] | None = None,
    ) -> ReferenceSolution:
        r"""Solve eq. (reference_calculation) for :math:`(\bar x, \bar u)`.

        Parameters
        ----------
        y0 : array_like, shape (p,)
            Normalized set-point :math:`y^0`.
        d_hat : array_like, shape (p,)
            Disturbance estimate :math:`\hat d`.
        warm : (x_bar, u_bar), optional
            Start point; default the previous solution (or a grid equilibrium).

        Raises
        ------
        UnreachableSetpointError
            In strict mode, when no admissible equilibrium is found.
        DimensionError
            When ``warm``'s parts are not of 2n and m values.
        """
        p = self.model.p
        if warm is not None:
            warm = (
                real_vector("warm x_bar", warm[0], 2 * self.model.n),
                real_vector("warm u_bar", warm[1], self.model.m),
            )
        return self.solve_arrays(real_vector("y0", y0, p), real_vector("d_hat", d_hat, p), warm)

    def solve_arrays(
        self,
        y0_arr: FloatArray,
        d_arr: FloatArray,
        warm: tuple[ArrayLike, ArrayLike] | None = None,
        *,
        chord: tuple[FloatArray, float, int, bool] | None = None,
    ) -> ReferenceSolution:
        """:meth:`solve` for arguments already checked: float64 arrays of shape (p,) with
        finite entries (the controller's hot path; nothing is checked here). ``chord``:
        the warm chord's outcome ``(z, residual, iterations, converged)`` where it already
        ran on this target (the controller's one-call step, which then calls
        :meth:`adopt_chord_state`); it is not run again."""
        model = self.model
        target = y0_arr - d_arr  # g(x_bar) must equal y0 - d_hat
        n2 = 2 * model.n
        folded: tuple[FloatArray, float] | None = None
        if warm is None and self._last_z is not None:
            z, norm, iterations, ok = chord if chord is not None else self._chord(target)
            u_bar = z[n2:]
            admissible = ok and max(map(abs, u_bar.tolist())) <= self.u_max * (1 + U_MARGIN)
            if admissible and model.m > 1 and float(np.abs(z - self._last_z).max()) > self.jump:
                # A MIMO equilibrium map can fold: a large jump may be another branch. Keep
                # it as a candidate and let the restarts find the closest admissible one.
                folded, admissible = (z, norm), False
            if admissible:
                self._last_z = z
                self._last_target = target
                return ReferenceSolution(
                    x_bar=z[:n2].copy(),  # copies: z is the next start (kept writeable, so
                    u_bar=u_bar.copy(),  # that the compiled code sees one array type)
                    residual=norm,
                    jacobian_condition=float("nan"),
                    u_admissible=True,
                    converged=True,
                    iterations=iterations,
                )
            self.counts["fallbacks"] += 1
            self._Jinv = None
        starts: list[FloatArray] = []
        if warm is not None:
            starts.append(np.concatenate([np.asarray(warm[0], float), np.asarray(warm[1], float)]))
        elif self._last_z is not None:
            starts.append(self._last_z.copy())
        previous = starts[0] if starts else None
        if self._restart_settings == (self.restarts, self.u_max):
            # the compiled twin of the loop below (whose numbers the one-call engine's are),
            # while its workspace holds the calculator's restarts and u_max
            z, norm, total_iterations, converged = self._restarts_compiled(
                previous, None if folded is None else folded[0], target
            )
            _F, A, B = self._residual(z, target)
            return self._restart_solution(
                y0_arr, d_arr, target, z, norm, total_iterations, converged, A, B
            )
        # Grid equilibria closest in output to the target (several for MIMO models, where
        # the equilibrium map can fold and distinct starts reach distinct equilibria).
        distance = np.max(np.abs(self._grid_y - target), axis=1)
        n_grid = 1 if model.m == 1 else min(self.restarts, distance.shape[0])
        for index in np.argsort(distance, kind="stable")[:n_grid]:
            starts.append(np.concatenate([self._grid_x[index], self._grid_u[index]]))
        if folded is not None:
            starts.insert(0, folded[0])  # converges at once (a Newton step from a solution)
        total_iterations = 0
        best: tuple[FloatArray, float, bool, FloatArray, FloatArray] | None = None
        best_rank: tuple[bool, float, bool, float] = (False, -np.inf, False, -np.inf)
        for number, z0 in enumerate(starts):
            z, norm, iterations, converged, A, B = self._newton(z0.copy(), target)
            total_iterations += iterations
            admissible = converged and bool(np.max(np.abs(z[n2:])) <= self.u_max * (1 + U_MARGIN))
            # Prefer an admissible solution, then the one closest to the previous solution
            # (continuity of the target), then a converged one, then the smallest residual.
            closeness = -float(np.max(np.abs(z - previous))) if previous is not None else 0.0
            rank = (admissible, closeness if admissible else -np.inf, converged, -norm)
            if best is None or rank > best_rank:
                best, best_rank = (z, norm, converged, A, B), rank
            if admissible and folded is None and (number == 0 or previous is None):
                break  # from the previous solution itself (or no previous one): take it
        assert best is not None
        z, norm, converged, A, B = best
        return self._restart_solution(
            y0_arr, d_arr, target, z, norm, total_iterations, converged, A, B
        )

    def _restarts_compiled(
        self, previous: FloatArray | None, folded: FloatArray | None, target: FloatArray
    ) -> tuple[FloatArray, float, int, bool]:
        """The restart loop of :meth:`solve_arrays` by its compiled twin
        (:func:`~ltv_lstm_mpc.loop.compiled_reference.newton_restarts`): (z, residual,
        Newton iterations of all starts, converged)."""
        parts = self._chord_parts
        assert parts is not None
        none = np.zeros(0)
        z = np.empty(self._jacobian.shape[0])
        norm, iterations, converged, _inside = newton_restarts(
            parts.workspace, parts.restart, none if previous is None else previous,
            none if folded is None else np.ascontiguousarray(folded), target, float(self.tol),
            int(self.max_iter), z,
        )  # fmt: skip
        return z, float(norm), int(iterations), bool(converged)

    def _restart_solution(
        self,
        y0_arr: FloatArray,
        d_arr: FloatArray,
        target: FloatArray,
        z: FloatArray,
        norm: float,
        total_iterations: int,
        converged: bool,
        A: FloatArray,
        B: FloatArray,
    ) -> ReferenceSolution:
        """The solution of the damped Newton with restarts, after a reset or where the warm
        path failed (its best point ``z`` with the Jacobians ``A``, ``B`` there), kept as
        the next warm start where admissible; raises in strict mode where it is not
        (:meth:`solve_arrays`)."""
        n2 = 2 * self.model.n
        x_bar, u_bar = z[:n2].copy(), z[n2:].copy()
        J = self._jacobian.copy()
        J[:n2, :n2] = A - self._eye
        J[:n2, n2:] = B
        condition = float(np.linalg.cond(J))
        u_admissible = bool(np.max(np.abs(u_bar)) <= self.u_max * (1 + U_MARGIN))
        solution = ReferenceSolution(
            x_bar=x_bar,
            u_bar=u_bar,
            residual=norm,
            jacobian_condition=condition,
            u_admissible=u_admissible,
            converged=converged,
            iterations=total_iterations,
        )
        if converged and u_admissible:
            self._last_z = z.copy()
            self._last_target = target
        if self.strict and not solution.ok:
            low, high = self.reachable_output_range
            reason = (
                f"Newton did not converge (residual {norm:.2e})"
                if not converged
                else f"it needs u_bar = {u_bar.tolist()} outside U = [-{self.u_max}, {self.u_max}]"
            )
            raise UnreachableSetpointError(
                f"set-point y0 = {y0_arr.tolist()} with d_hat = {d_arr.tolist()} is not reachable: "
                f"{reason}. The model's equilibrium output over U spans [{low.tolist()}, "
                f"{high.tolist()}] (normalized), so y0 - d_hat must lie in it; choose y0 inside, "
                "or pass strict=False to get the flagged solution."
            )
        return solution
