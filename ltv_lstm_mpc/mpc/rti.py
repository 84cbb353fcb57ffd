r"""Robust MPC of eq. (optimization) by real-time iterations (paper notes section 4): the one core.

At step k the LSTM is linearized along the candidate of the proof of Theorem 3
(Part 2b): the previous optimal inputs shifted by one, with :math:`\bar u_k` appended
(:math:`\bar u_k` repeated at the first step). One convex subproblem
(:class:`~ltv_lstm_mpc.mpc.sparse.FHOCPSubproblem`) is solved; with
``sqp_iterations > 1`` a globalized SQP (:mod:`~ltv_lstm_mpc.mpc.sqp`: merit line
search, feasibility phase, KKT-residual stopping) iterates to the nonlinear FHOCP's
solution. Every plan is
re-simulated on the true LSTM and its nonlinear constraint residuals are recorded: a
linearized solution is a proposal, not a certificate.

Infeasibility (the i = 0 output row fails, :math:`\alpha_k \le 0`, or the solve
fails) triggers the configured policy (then, if that fails too, ``"<policy>+shift"``):

``"paper"``
    re-solve without the output and terminal constraints (paper, Fig. 5);
``"soft"``
    re-solve with exact-penalty slacks on the output rows and the terminal level;
``"shift"``
    apply the shifted previous plan (the candidate).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.caller_warnings import warn_at_caller
from ltv_lstm_mpc.certificates.certify import Certification, certify, u_max_extrapolation
from ltv_lstm_mpc.deferred_state import Deferred, DeferredSetting, DeferredState, settle
from ltv_lstm_mpc.exceptions import DimensionError, InvalidValueError, LtvMpcError
from ltv_lstm_mpc.lstm.model import LSTMModel, require_model
from ltv_lstm_mpc.mpc.compiled_plan import new_plan_workspace, plan_metrics
from ltv_lstm_mpc.mpc.compiled_prepare import (
    CANDIDATE_GIVEN,
    CANDIDATE_SHIFT,
    CANDIDATE_U_BAR,
    new_prepare_workspace,
)
from ltv_lstm_mpc.mpc.config import MPCConfig, require_config
from ltv_lstm_mpc.mpc.fhocp import (
    MPCSolution,
    MPCSolver,
    PlanCost,
    plan_residuals,
    precheck_status,
    shifted_candidate,
)
from ltv_lstm_mpc.mpc.kernels import compiled_kernels
from ltv_lstm_mpc.mpc.sqp import SQPOutcome, Subproblem, globalized_sqp
from ltv_lstm_mpc.mpc.transcription import (
    NLP_SOLVERS,
    StepResult,
    TranscriptionBase,
    resolve_transcription,
)
from ltv_lstm_mpc.solvers import ConvexProblem, DenseQP, SolverStatus
from ltv_lstm_mpc.validation import expect_bool, expect_instance, expect_real, real_vector

if TYPE_CHECKING:
    from ltv_lstm_mpc.mpc.sparse import FHOCPSubproblem

__all__ = [
    "NLP_SOLVERS",
    "MPCConfig",
    "MPCSolution",
    "MPCSolver",
    "OneCallParts",
    "RobustMPC",
    "compiled_kernels",
    "resolve_transcription",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class OneCallParts:
    """The compiled parts of :class:`RobustMPC`'s RTI step (:meth:`RobustMPC.one_call_parts`).

    Attributes
    ----------
    trajectories, condensing, plan : workspaces
        The preparation's (:func:`~ltv_lstm_mpc.mpc.compiled_prepare.prepare_condensed`),
        the condensing's and the plan checks' typed workspaces.
    candidate : ndarray (N, m)
        The candidate buffer (Theorem 3, Part 2b).
    daqp, socp : workspace or None
        The one-call feedback's solver workspace: DAQP's QP
        (:func:`~ltv_lstm_mpc.mpc.native_feedback.nominal_feedback`) or the exact cones by SQP
        on DAQP (:func:`~ltv_lstm_mpc.mpc.native_feedback.cone_feedback`); one is None.
    fallback : workspace or None
        The infeasibility policy's buffers
        (:func:`~ltv_lstm_mpc.mpc.native_feedback.policy_feedback`, and with ``socp`` the
        session workspaces of :func:`~ltv_lstm_mpc.mpc.native_feedback.cone_policy_feedback`).
    flag_outcome : callable or None
        With ``daqp``: the status and reason of a DAQP exit flag
        (:func:`~ltv_lstm_mpc.mpc.native_feedback.feedback_outcome`).
    socp_arrays, failure_outcome : dict, callable or None
        With ``socp``: the arrays of the workspace a failed nominal problem is solved on
        again (the ``"nominal"`` session's, held in ``fallback``:
        :func:`~ltv_lstm_mpc.mpc.native_feedback.cone_policy_feedback`), and the status
        and reason of that failed solve from a copy of them
        (``TranscriptionBase.failure_outcome``).
    failure_snapshot : tuple or None
        With ``socp``: the flat arrays the one-call feedback copies a failed solve's
        ``socp_arrays`` into, in the step
        (:func:`~ltv_lstm_mpc.solvers.socp_sqp.snapshot_into`).
    tolerance : float
        The acceptance tolerance of the cone feedback.
    backward : bool
        The condensing's recursion.
    """

    trajectories: Any
    condensing: Any
    plan: Any
    candidate: FloatArray
    daqp: Any
    socp: Any
    tolerance: float
    backward: bool
    fallback: Any = None
    flag_outcome: Any = None
    socp_arrays: Any = None
    failure_outcome: Any = None
    failure_snapshot: Any = None


class RobustMPC(DeferredState):
    r"""The robust MPC of eq. (optimization), one RTI core for every transcription.

    Parameters
    ----------
    model : LSTMModel
        Needs m = p (Assumption 1).
    config : MPCConfig, optional
        Every field is honoured; ``solver`` and ``transcription`` choose the
        transcription (:func:`resolve_transcription`).
    certification : Certification, optional
        Precomputed certificates (default: :func:`~ltv_lstm_mpc.certify`
        with ``config.certification_settings(model)``).
    reuse_tol : float
        When the linearization start is within this distance (inf-norm) of the previous
        plan's predicted :math:`x_{1|k-1}`, the previous re-simulation is shifted instead
        of simulated again (the prediction *is* that trajectory).
    native_feedback : bool
        Run the nominal feedback as one compiled call where it exists (condensed QP with
        DAQP bound natively, compiled kernel, one SQP iteration; see
        :mod:`~ltv_lstm_mpc.mpc.native_feedback`); it accepts only points the general path
        accepts and hands everything else to it. ``False``: always the general path.
    **transcription_options
        Extra options of the transcription (the nonlinear one takes ``smoothing``).

    Attributes
    ----------
    transcription : str
        ``"condensed"``, ``"sparse"`` or ``"nonlinear"``.
    reformulation : str or None
        The conservative cone reformulation of a QP-only backend, or None (exact cones).
    prepare_time, feedback_time, solver_time : float
        Wall times of the last :meth:`prepare`, :meth:`feedback` and solver calls, s.
    """

    # The previous plan and the last times (a one-call step of the controller may leave
    # them deferred in its record row: ltv_lstm_mpc.deferred_state).
    _previous_u = Deferred[FloatArray | None]()
    prepare_time = Deferred[float]()
    feedback_time = Deferred[float]()
    solver_time = Deferred[float]()
    qp_iterations = Deferred[int]()
    # A setting the controller's one-call workspace holds (assigning it ends a deferral).
    reuse_tol = DeferredSetting[float]()

    def __init__(
        self,
        model: LSTMModel,
        config: MPCConfig | None = None,
        *,
        certification: Certification | None = None,
        reuse_tol: float = 1e-9,
        native_feedback: bool = True,
        **transcription_options: Any,
    ) -> None:
        model, config = require_model(model), require_config(config)
        if certification is not None:
            expect_instance(
                "certification",
                certification,
                Certification,
                "compute one with certify(model, config.certification_settings(model))",
                expected="a Certification or None",
            )
        expect_real("reuse_tol", reuse_tol, low=0.0)
        expect_bool("native_feedback", native_feedback)
        model.require_square()
        self.model = model
        self.config = config = config or MPCConfig()
        self.transcription = kind = resolve_transcription(config)
        self.certification = certification or certify(model, config.certification_settings(model))
        self.tightening = ti = self.certification.tightening
        ti.require_setpoint_interval(model.denormalize_y if model.normalization else None)
        extrapolation = u_max_extrapolation(model, config.u_max)
        if extrapolation is not None:
            warn_at_caller(extrapolation, RuntimeWarning)
        Q, R = config.weights(model)
        self.N = N = config.N
        kinds: tuple[str, ...] = ("nominal",)
        if config.infeasibility_policy != "shift":
            kinds = ("nominal", config.infeasibility_policy)
        if config.sqp_iterations > 1 and "soft" not in kinds:
            kinds += ("soft",)  # the globalized SQP's feasibility phase (mpc/sqp.py)
        self._problem: TranscriptionBase
        if kind == "condensed":
            from ltv_lstm_mpc.mpc.condensed import CondensedTranscription

            self._problem = CondensedTranscription(model, config, ti, Q, R, kinds)
        elif kind == "sparse":
            from ltv_lstm_mpc.mpc.sparse import SparseTranscription

            self._problem = SparseTranscription(model, config, ti, Q, R, kinds)
        else:
            from ltv_lstm_mpc.mpc.nmpc import NonlinearTranscription

            self._problem = NonlinearTranscription(
                model, config, ti, Q, R, kinds, **transcription_options
            )
        if transcription_options and kind != "nonlinear":
            raise InvalidValueError(
                f"unknown option(s) {sorted(transcription_options)} for the {kind} transcription"
            )
        self.reformulation = self._problem.reformulation
        self.solver = config.solver
        self.reuse_tol = float(reuse_tol)
        self._cost = PlanCost(Q, R, np.asarray(ti.P_f), model.n)
        # buffers of the compiled plan checks (mpc/compiled_plan.plan_metrics)
        self._Q = np.ascontiguousarray(Q, dtype=np.float64)
        self._Q_diagonal = bool(np.all(self._Q == np.diag(np.diag(self._Q))))
        self._R = np.ascontiguousarray(R, dtype=np.float64)
        self._P_terms = np.array(self._cost.terminal_terms)
        self._metrics = np.zeros(4)
        self._no_rows = np.zeros((0, 2 * model.n))
        self._W_y = np.ascontiguousarray(model.W_y)
        self._b_y = np.ascontiguousarray(model.b_y)
        kernel = model.kernel
        self._kernel = kernel
        self._traj = kernel.trajectory(N)
        self._plan = kernel.trajectory(N)
        #: Whether the last feedback left a plan the next candidate shifts.
        self.plan_valid = False
        self._cand = np.empty((N, model.m))
        # Typed workspaces of the compiled calls (None on the numpy kernel): the plan checks,
        # the preparation's trajectories, the transcription's condensing buffers.
        self._plan_workspace: Any = None
        self._prepare_workspace: Any = None
        self._condensing_workspace: Any = None
        #: The plan checks of the feedback, chosen once: compiled twin or numpy reference.
        self._check_plan = self._check_plan_numpy
        if kernel.compiled:
            self._check_plan = self._check_plan_compiled
            from ltv_lstm_mpc.numba_support import announce_compile

            announce_compile(
                compiled_kernels(config, native_feedback=native_feedback),
                "the controller kernels",
                "20-40 s",
            )
            plan, traj = self._plan, self._traj
            self._plan_workspace = new_plan_workspace(
                WU=kernel.WU,
                S=plan.S,
                T=plan.T,
                TC=plan.TC,
                W_y=self._W_y,
                b_y=self._b_y,
                Q=self._Q,
                R=self._R,
                P_terms=self._P_terms,
                out=self._metrics,
                Q_diagonal=self._Q_diagonal,
            )
            self._condensing_workspace = self._problem.workspace(traj)  # binds traj
            if self._condensing_workspace is not None:
                self._prepare_workspace = new_prepare_workspace(
                    WU=kernel.WU,
                    WU_raw=kernel.WU_raw,
                    S=traj.S,
                    T=traj.T,
                    TC=traj.TC,
                    J=traj.J,
                    PS=plan.S,
                    PT=plan.T,
                    PTC=plan.TC,
                )
        self._W_y_T = np.ascontiguousarray(model.W_y.T)
        self._bounds_key: tuple[float, bytes] | None = None
        self._bounds_e: float | None = None
        self._previous_u = None
        self._prepared = False
        self._u_bar_projected = False  # the last candidate appends u_bar projected onto U
        # One compiled call for the nominal feedback where the transcription offers it
        # (condensed QP, DAQP bound natively, compiled kernel; one SQP iteration).
        self._native_feedback: Any = None
        self._one_call_parts: OneCallParts | None = None  # (one_call_parts)
        if self._prepare_workspace is not None and config.sqp_iterations == 1 and native_feedback:
            from ltv_lstm_mpc.mpc import native_feedback as one_call_feedback

            problem = self._problem
            daqp, socp = problem.daqp_workspace, problem.socp_workspace
            feedback = None
            if daqp is not None:  # the QP on DAQP
                feedback = one_call_feedback.nominal_feedback
            elif socp is not None:  # the exact cones by SQP on DAQP (daqp:socp)
                feedback = one_call_feedback.cone_feedback
            self._native_feedback = feedback
            self._one_call_parts = None if feedback is None else OneCallParts(
                trajectories=self._prepare_workspace, condensing=self._condensing_workspace,
                plan=self._plan_workspace, candidate=self._cand, daqp=daqp, socp=socp,
                tolerance=float(problem.tolerance),
                backward=bool(getattr(problem, "backward_condensing", False)),
                fallback=problem.fallback_workspace, flag_outcome=problem.flag_outcome,
                socp_arrays=problem.socp_arrays, failure_outcome=problem.failure_outcome,
                failure_snapshot=problem.failure_snapshot,
            )  # fmt: skip
        self.prepare_time = self.feedback_time = self.solver_time = 0.0
        self.qp_iterations = 0

    # ------------------------------------------------------------- for a step engine
    def one_call_parts(self) -> OneCallParts | None:
        """The compiled parts a one-call step engine runs this MPC's RTI step with
        (:class:`OneCallParts`); None where there is no one-call feedback (another
        transcription or solver, the solver not bound natively, the numpy kernel, a
        globalized SQP, ``native_feedback=False``)."""
        return self._one_call_parts

    @property
    def previous_plan(self) -> FloatArray | None:
        """The last applied plan :math:`u_{\\cdot|k-1}` (N, m), the candidate's source; None
        after :meth:`reset`."""
        return self._previous_u

    def settle_plan(
        self, previous_u: FloatArray, times: tuple[float, float, float], iterations: int
    ) -> None:
        """Take the plan a compiled step left in its record row (a view, never written
        again), with its (solver, prepare, feedback) times and solver iterations, ending a
        deferral (:mod:`ltv_lstm_mpc.deferred_state`)."""
        solver_time, prepare_time, feedback_time = times
        settle(self, {
            "_previous_u": previous_u, "solver_time": solver_time,
            "prepare_time": prepare_time, "feedback_time": feedback_time,
            "qp_iterations": iterations,
        })  # fmt: skip

    def forget_preparation(self) -> None:
        """A compiled step prepared and solved outside this object: its transcription's
        scaling and solved subproblems are not this step's (:meth:`prepare` sets them again
        before any feedback here)."""
        self._problem.forget_preparation()

    # ---------------------------------------------------------------------------- state
    def reset(self) -> None:
        """Forget the previous plan (the next candidate is u_bar repeated)."""
        self._previous_u = None
        self.plan_valid = False
        self._prepared = False
        self._problem.reset()

    def candidate(self, u_bar: FloatArray) -> FloatArray:
        """Proof candidate (Theorem 3, Part 2b): the previous plan shifted by one with
        :math:`\\bar u` appended, projected onto U where :math:`\\bar u` lies outside it
        (an inadmissible equilibrium), as :meth:`prepare` builds it."""
        u_max = self.config.u_max
        return shifted_candidate(self._previous_u, np.clip(u_bar, -u_max, u_max), self.N)

    def _bounds(self, y0: FloatArray, e_hat: float) -> None:
        """Tightened bounds and alpha_k from :class:`TighteningCertificate`, when they change."""
        ti = self.tightening
        if e_hat != self._bounds_e:
            self._lower, self._upper = ti.output_bounds(e_hat)
            self._row0 = (self._lower[0].tolist(), self._upper[0].tolist())
            self._bounds_e = e_hat
            self._bounds_key = None
        key = (e_hat, y0.tobytes())
        if key != self._bounds_key:
            self._alpha = ti.alpha(y0, e_hat)
            self._bounds_key = key

    # -------------------------------------------------------------------------- prepare
    def subproblem(self, kind: str = "nominal") -> FHOCPSubproblem:
        """The builder of the sparse transcription's subproblem ``kind``
        (:meth:`~ltv_lstm_mpc.mpc.sparse.SparseTranscription.subproblem`): what replay tools
        rebuild a step's convex subproblem with.

        Raises
        ------
        InvalidValueError
            If this controller's transcription is not ``"sparse"``.
        """
        from ltv_lstm_mpc.mpc.sparse import SparseTranscription

        if not isinstance(self._problem, SparseTranscription):
            raise InvalidValueError(
                f"subproblem() needs transcription='sparse'; this controller's is "
                f"{self.transcription!r}"
            )
        return self._problem.subproblem(kind)

    def condensing_workspace(self) -> Any:
        """The compiled condensing's buffers on this controller's linearization trajectory
        (:data:`~ltv_lstm_mpc.mpc.compiled_condensing.CondensingWorkspace`, what
        :func:`~ltv_lstm_mpc.mpc.compiled_condensing.condense` takes), or None when the
        transcription is not the condensed one on a compiled kernel. For timing and
        checking the condensing alone (``experiments/condensing_speed.py``)."""
        return self._problem.workspace(self._traj)

    def last_problem(self, kind: str = "nominal") -> ConvexProblem | DenseQP:
        """The convex subproblem of eq. (optimization) solved at the last step, exactly as
        the backend got it: what replay tools save and re-solve with other backends.

        The sparse transcription gives its :class:`~ltv_lstm_mpc.solvers.ConvexProblem`
        (exact cones; ``subproblem(kind).reformulation.apply`` gives the QP form); the
        condensed one a copy of its :class:`~ltv_lstm_mpc.solvers.DenseQP` (kept on the
        general feedback path: ``RobustMPC(..., native_feedback=False)`` for the nominal
        QP of a natively bound DAQP).

        Raises
        ------
        InvalidValueError
            The transcription is ``"nonlinear"``, or ``kind`` was not solved at the last
            step.
        """
        return self._problem.last_problem(kind)

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
        r"""Linearize and build before the estimate arrives (acados ``prepare``).

        Parameters
        ----------
        x_bar, u_bar : (2n,), (m,)
            Reference-calculator set-points :math:`\bar x_k, \bar u_k`.
        y0 : (p,)
            Normalized set-point (enters :math:`\alpha_k`, eq. def_alpha).
        e_hat : float
            Observer-error bound :math:`\hat e_{o,k}` (tightening, eq. optimization).
        x_pred : (2n,), optional
            Predicted :math:`\hat x_k` to linearize from; default the previous plan's
            :math:`x_{1|k-1}` (required at the first call).
        warm : (N, m), optional
            Inputs to linearize along (default: the proof candidate).
        """
        start = time.perf_counter()
        model, N = self.model, self.N
        n2, m = 2 * model.n, model.m
        self._x_bar = x_bar_a = np.asarray(x_bar, dtype=np.float64)
        self._u_bar = u_bar_a = np.asarray(u_bar, dtype=np.float64).reshape(m)
        self._bounds(np.asarray(y0, dtype=np.float64).reshape(model.p), float(e_hat))
        cand, plan = self._cand, self._plan
        # the candidate (Theorem 3, Part 2b) and the start of the linearization
        u_max = self.config.u_max
        self._u_bar_projected = False
        if warm is not None:
            cand[:] = np.asarray(warm, dtype=np.float64).reshape(N, m)
            candidate = CANDIDATE_GIVEN
        elif any(not -u_max <= v <= u_max for v in u_bar_a.tolist()):
            # An inadmissible equilibrium (unreachable set-point, or a failed reference):
            # the candidate appends u_bar's projection onto U, so that no plan built on it
            # (the "shift" policy and every "+shift" fallback apply it) leaves U.
            u_projected = np.clip(u_bar_a, -u_max, u_max)
            self._u_bar_projected = True
            if self._previous_u is None:
                cand[:] = u_projected
            else:
                cand[:-1] = self._previous_u[1:]
                cand[-1] = u_projected
            candidate = CANDIDATE_GIVEN
        elif self._previous_u is None:
            candidate = CANDIDATE_U_BAR
        else:
            candidate = CANDIDATE_SHIFT
        if x_pred is None:
            if not self.plan_valid:
                raise InvalidValueError("the first prepare() needs x_pred (no previous plan)")
            x0 = plan.S[1, :n2]
        else:
            x0 = np.ascontiguousarray(x_pred, dtype=np.float64)
        # the re-simulation of the previous plan may replace the rollout (x0 at its x_1)
        reuse_allowed = warm is None and self.plan_valid
        previous_u = cand if self._previous_u is None else self._previous_u
        if self._prepare_workspace is None or not self._problem.linearize_and_build(
            self._prepare_workspace, cand, previous_u, candidate, x0, reuse_allowed,
            self.reuse_tol, x_bar_a, u_bar_a, self._lower, self._upper, self._alpha,
        ):  # fmt: skip
            self._linearize_numpy(previous_u, candidate, x0, reuse_allowed, x_bar_a, u_bar_a)
        self._prepared = True
        self.prepare_time = time.perf_counter() - start

    def _linearize_numpy(
        self,
        previous_u: FloatArray,
        candidate: int,
        x0: FloatArray,
        reuse_allowed: bool,
        x_bar: FloatArray,
        u_bar: FloatArray,
    ) -> None:
        """The preparation's candidate, rollout (or the shifted re-simulation), Jacobians and
        :meth:`~ltv_lstm_mpc.mpc.transcription.TranscriptionBase.build` in Python: the
        readable reference of
        :func:`~ltv_lstm_mpc.mpc.compiled_prepare.prepare_condensed` (tested against it),
        and the path of every transcription without that one call."""
        N, n2, m = self.N, 2 * self.model.n, self.model.m
        cand, traj, plan, kernel = self._cand, self._traj, self._plan, self._kernel
        if candidate == CANDIDATE_U_BAR:
            cand[:] = u_bar
        elif candidate == CANDIDATE_SHIFT:
            cand[:-1] = previous_u[1:]
            cand[-1] = u_bar
        S = traj.S
        if reuse_allowed and float(np.abs(x0 - plan.S[1, :n2]).max()) <= self.reuse_tol:
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
        self._problem.build(traj, x_bar, u_bar, self._lower, self._upper, self._alpha)

    def _check_plan_compiled(
        self, u: FloatArray, x_linear: FloatArray | None, alpha: float
    ) -> tuple[FloatArray, float, dict[str, float]]:
        """Re-simulation of the plan in ``_plan`` (state and inputs written), its cost and
        nonlinear residuals, in one numba call (``mpc/compiled_plan.py``)."""
        N, n2 = self.N, 2 * self.model.n
        x_plan = np.empty((N + 1, n2))
        metrics = self._metrics
        plan_metrics(
            self._plan_workspace, self._x_bar, self._u_bar, self._lower, self._upper,
            self._no_rows if x_linear is None else x_linear, x_plan,
        )  # fmt: skip
        residuals = {
            "output_violation": float(metrics[2]),
            "terminal_residual": float(metrics[1]) - alpha,
            "linearization_gap": float(metrics[3]),
        }
        return x_plan, float(metrics[0]), residuals

    def _check_plan_numpy(
        self, u: FloatArray, x_linear: FloatArray | None, alpha: float
    ) -> tuple[FloatArray, float, dict[str, float]]:
        """:meth:`_check_plan_compiled` in numpy (the reference): the kernel's rollout,
        :class:`~ltv_lstm_mpc.mpc.fhocp.PlanCost` and
        :func:`~ltv_lstm_mpc.mpc.fhocp.plan_residuals`."""
        N, n = self.N, self.model.n
        self._kernel.rollout(self._plan, 0, N)
        x_plan = self._plan.S[:, : 2 * n].copy()
        y_plan = x_plan[:N, n:] @ self._W_y_T
        y_plan += self.model.b_y
        cost, terminal_norm = self._cost.evaluate(x_plan, u, self._x_bar, self._u_bar)
        residuals = plan_residuals(
            terminal_norm, x_plan, y_plan, x_linear, (self._lower, self._upper), alpha
        )
        return x_plan, cost, residuals

    # ------------------------------------------------------------------------- feedback
    def _checked_solve(self, kind: str, x_hat: FloatArray) -> tuple[StepResult, str, str]:
        """Solve ``kind`` and validate the point: (result, status name, reason)."""
        try:
            result = self._problem.solve(kind, x_hat)
        except Exception as error:
            reason = f"{self.solver} raised {type(error).__name__}: {error}"
            empty = StepResult(SolverStatus.FAILED, None, None, float("nan"), 0.0, 0.0, 0)
            return empty, "solver_error", reason
        status = result.status
        if not status.has_solution or result.u is None:
            return result, status.name.lower(), result.info
        u, x_linear = result.u, result.x_linear
        # One sum for the hot path: a NaN/inf entry makes it non-finite (so does an
        # overflowing sum of huge entries, rejected as well).
        if x_linear is None or not math.isfinite(float(u.sum()) + float(x_linear.sum())):
            result.u = None
            reason = f"{self.solver} returned a non-finite (or overflowing) point ({result.info})"
            return result, "failed", reason
        u_max, tol = self.config.u_max, result.tolerance
        outside = float(np.abs(u).max()) - u_max
        if outside > tol * (1.0 + u_max):
            result.u = None
            reason = (
                f"{self.solver} returned inputs outside U by {outside:.3e} (tolerance {tol:.1e})"
            )
            return result, "failed", reason
        if not result.violation <= tol:
            result.u = None
            reason = (
                f"{self.solver} returned a point violating its {self.transcription} problem by "
                f"{result.violation:.3e} (relative; tolerance {tol:.1e})"
            )
            return result, "failed", reason
        if outside > 0.0:  # within the solver's tolerance: clip onto U
            np.clip(u, -u_max, u_max, out=u)
        name = "optimal_inaccurate" if status is SolverStatus.OPTIMAL_INACCURATE else "optimal"
        return result, name, ""

    def feedback(self, x_hat: ArrayLike, *, native: bool = True) -> MPCSolution:
        r"""Insert :math:`\hat x_k`, solve, validate, re-simulate (acados ``feedback``).

        Parameters
        ----------
        x_hat : array_like (2n,)
        native : bool
            Try the one-call feedback first where it exists (default); False skips it (a
            compiled step engine has run it on this point and it declined).

        Returns
        -------
        MPCSolution
            ``solve_time`` is prepare + feedback time; ``solver_time`` the solver calls.
        """
        start = time.perf_counter()
        if not self._prepared:
            raise LtvMpcError("feedback() needs a prepare() first")
        self._prepared = False
        model, config, N = self.model, self.config, self.N
        n, m = model.n, model.m
        n2 = 2 * n
        x_hat_a = np.ascontiguousarray(x_hat, dtype=np.float64)
        alpha = self._alpha
        if native and self._native_feedback is not None:
            solution = self._feedback_native(x_hat_a, start)
            if solution is not None:
                return solution
        y_first = (self._W_y_T.T @ x_hat_a[n:] + model.b_y).tolist()
        status = precheck_status(y_first, *self._row0, alpha)
        reason = status
        solver_time = 0.0
        iterations = 0
        sqp = 0
        step = 0.0
        u_plan: FloatArray | None = None
        x_linear: FloatArray | None = None
        kkt_residual = float("nan")
        feasibility_steps = 0
        step_length = 1.0
        sqp_reason = ""
        if not status and config.sqp_iterations == 1:  # RTI: one subproblem
            result, name, why = self._checked_solve("nominal", x_hat_a)
            solver_time += result.solver_time
            iterations += result.iterations
            if result.u is None:
                status, reason = name, why
            else:
                sqp = 1
                status = name
                step = float(np.abs(result.u - self._cand).max())
                u_plan, x_linear = result.u, result.x_linear
        elif not status:  # globalized SQP (mpc/sqp.py)
            outcome, solver_time, iterations = self._globalized_sqp(x_hat_a)
            status, sqp, step = outcome.status, outcome.iterations, outcome.step
            kkt_residual, feasibility_steps = outcome.kkt_residual, outcome.feasibility_steps
            step_length, sqp_reason = outcome.step_length, outcome.reason
            reason = sqp_reason
            if outcome.status != "infeasible":
                u_plan, x_linear = outcome.u, outcome.x_linear
            elif outcome.iterations:  # the fallback below is posed on the candidate
                self._relinearize(x_hat_a, self._cand)
        feasible = status in ("optimal", "optimal_inaccurate")
        policy = "nominal"
        if not feasible:
            u_plan = x_linear = None
            policy = config.infeasibility_policy
            if policy != "shift":  # on the candidate's linearization
                result, _, _ = self._checked_solve(policy, x_hat_a)
                solver_time += result.solver_time
                iterations += result.iterations
                if result.u is None:
                    policy = f"{policy}+shift"
                else:
                    u_plan, x_linear = result.u, result.x_linear
                    step = float(np.abs(u_plan - self._cand).max())
                    sqp = max(sqp, 1)
        if u_plan is None:
            u_plan = self._cand.copy()
            step = 0.0
            if self._u_bar_projected:
                reason += "; the candidate applied appends u_bar projected onto U"
        # ---- re-simulate the plan on the true LSTM (nonlinear residuals)
        P = self._plan.S
        P[0, :n2] = x_hat_a
        P[:N, n2 : n2 + m] = u_plan
        self.plan_valid = True
        u_out = np.array(u_plan)
        self._previous_u = u_out
        x_plan, cost, residuals = self._check_plan(u_out, x_linear, alpha)
        self.solver_time = solver_time
        self.qp_iterations = iterations
        self.feedback_time = time.perf_counter() - start
        return MPCSolution(
            u=u_out,
            x=x_plan,
            x_linear=np.full((N + 1, n2), np.nan) if x_linear is None else x_linear,
            status=status,
            feasible=feasible,
            policy=policy,
            solve_time=self.prepare_time + self.feedback_time,
            solver_time=solver_time,
            iterations=sqp,
            sqp_step=step,
            alpha=alpha,
            cost=cost,
            residuals=residuals,
            reformulation=self.reformulation,
            solver_iterations=iterations,
            transcription=self.transcription,
            prepare_time=self.prepare_time,
            feedback_time=self.feedback_time,
            reason=reason if not feasible else sqp_reason,
            kkt_residual=kkt_residual,
            feasibility_steps=feasibility_steps,
            step_length=step_length,
        )

    def _feedback_native(self, x_hat: FloatArray, start: float) -> MPCSolution | None:
        """The nominal feedback in one compiled call (mpc/native_feedback.py); ``None`` when
        it does not accept the point (the general path of :meth:`feedback` then runs)."""
        N, n2, m = self.N, 2 * self.model.n, self.model.m
        problem, alpha = self._problem, self._alpha
        daqp, socp = problem.daqp_workspace, problem.socp_workspace
        if daqp is None and socp is None:
            return None
        u = np.empty((N, m))
        x_linear = np.empty((N + 1, n2))
        x_plan = np.empty((N + 1, n2))
        metrics = self._metrics
        if daqp is not None:
            code, iterations, step, solver_time = self._native_feedback(
                self._condensing_workspace, daqp, self._plan_workspace, x_hat, self._x_bar,
                self._u_bar, self._lower, self._upper, alpha, problem.scale, x_linear, u,
                x_plan,
            )  # fmt: skip
        else:
            code, iterations, step, solver_time, flag, sqp = self._native_feedback(
                self._condensing_workspace, socp, self._plan_workspace, x_hat, self._x_bar,
                self._u_bar, self._lower, self._upper, alpha, problem.scale,
                problem.tolerance, x_linear, u, x_plan,
            )  # fmt: skip
            if code < 0:  # (native_feedback.STATUS_CONE_FAILURE: the SQP failed) the
                # general path takes this solve's outcome rather than solving again
                problem.adopt_failed_solve(flag, sqp, iterations, solver_time)
                return None
        if not code:
            return None
        self.plan_valid = True
        self._previous_u = u
        self.solver_time = solver_time
        self.qp_iterations = iterations
        self.feedback_time = feedback_time = time.perf_counter() - start
        prepare_time = self.prepare_time
        return MPCSolution(
            u=u,
            x=x_plan,
            x_linear=x_linear,
            status="optimal" if code == 1 else "optimal_inaccurate",
            feasible=True,
            policy="nominal",
            solve_time=prepare_time + feedback_time,
            solver_time=solver_time,
            iterations=1,
            sqp_step=step,
            alpha=alpha,
            cost=float(metrics[0]),
            residuals={
                "output_violation": float(metrics[2]),
                "terminal_residual": float(metrics[1]) - alpha,
                "linearization_gap": float(metrics[3]),
            },
            reformulation=self.reformulation,
            solver_iterations=iterations,
            transcription=self.transcription,
            prepare_time=prepare_time,
            feedback_time=feedback_time,
            reason="",
        )

    def _globalized_sqp(self, x_hat: FloatArray) -> tuple[SQPOutcome, float, int]:
        """:func:`~ltv_lstm_mpc.mpc.sqp.globalized_sqp` on this core from ``x_hat``:
        (outcome, solver seconds, solver iterations)."""
        N, n, m = self.N, self.model.n, self.model.m
        n2 = 2 * n
        alpha, x_bar, u_bar = self._alpha, self._x_bar, self._u_bar
        bounds = (self._lower, self._upper)
        spent = [0.0, 0]

        def linearize(u: FloatArray) -> FloatArray:
            self._relinearize(x_hat, u)
            return self._traj.S[:, :n2].copy()

        def solve(kind: str) -> Subproblem:
            result, name, why = self._checked_solve(kind, x_hat)
            spent[0] += result.solver_time
            spent[1] += result.iterations
            return Subproblem(result.u, result.x_linear, name, why, result.tolerance)

        terminal = self._cost.terminal_set
        box = self.reformulation is not None  # QP-only: the subproblem's terminal box
        half_widths = alpha * terminal.unit_half_widths

        def merit_terms(
            x: FloatArray, cost: float, terminal_norm: float, output_violation: float
        ) -> tuple[float, float]:
            """(J, theta) of the NLP the subproblems linearize: eq. (optimization), or with
            a QP-only backend its box reformulation (mpc/terminal.py: the terminal cost
            bound and the box inside X_f)."""
            if not box:
                return cost, max(0.0, output_violation, terminal_norm - alpha)
            deviation = x[N] - x_bar
            cost += float(terminal.box_weights @ deviation**2) - terminal_norm**2
            outside = float((np.abs(deviation) - half_widths).max())
            return cost, max(0.0, output_violation, outside)

        def evaluate(u: FloatArray) -> tuple[float, float]:
            P = self._plan.S
            P[0, :n2] = x_hat
            P[:N, n2 : n2 + m] = u
            x, cost, residuals = self._check_plan(u, None, alpha)
            self.plan_valid = False  # not the applied plan
            terminal_norm = residuals["terminal_residual"] + alpha
            return merit_terms(x, cost, terminal_norm, residuals["output_violation"])

        def evaluate_linear(x: FloatArray, u: FloatArray) -> tuple[float, float]:
            cost, terminal_norm = self._cost.evaluate(x, u, x_bar, u_bar)
            y = x[:N, n:] @ self._W_y_T + self.model.b_y
            residuals = plan_residuals(terminal_norm, x, y, None, bounds, alpha)
            return merit_terms(x, cost, terminal_norm, residuals["output_violation"])

        outcome = globalized_sqp(
            self._cand,
            linearize=linearize,
            solve=solve,
            evaluate=evaluate,
            evaluate_linear=evaluate_linear,
            iterations=self.config.sqp_iterations,
            tolerance=self.config.sqp_tolerance,
            penalty=self.config.soft_penalty,
        )
        return outcome, float(spent[0]), int(spent[1])

    def _relinearize(self, x_hat: FloatArray, u_lin: FloatArray) -> None:
        """Roll out and linearize from ``x_hat`` along ``u_lin`` and rebuild (SQP step)."""
        traj = self._traj
        n2, m = 2 * self.model.n, self.model.m
        traj.S[0, :n2] = x_hat
        traj.S[: self.N, n2 : n2 + m] = u_lin
        self._kernel.rollout(traj, 0, self.N)
        self._kernel.jacobians(traj)
        self._problem.build(traj, self._x_bar, self._u_bar, self._lower, self._upper, self._alpha)

    # ---------------------------------------------------------------------------- solve
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
        r"""Solve the FHOCP at :math:`(\hat x_k, \bar x_k, \bar u_k, y^0_k, \hat e_{o,k})`.

        Checks the arguments, then :meth:`prepare` from :math:`\hat x_k` and
        :meth:`feedback`.

        Parameters
        ----------
        x_hat : (2n,)
            Observer estimate :math:`\hat x_k` (eq. optimization_initialization).
        x_bar, u_bar : (2n,), (m,)
            Reference-calculator set-points.
        y0 : (p,)
            Normalized set-point (enters :math:`\alpha_k`).
        e_hat : float
            Observer-error bound :math:`\hat e_{o,k}`.
        warm : (N, m), optional
            Input sequence to linearize along; default the shifted previous plan with
            :math:`\bar u_k` appended (the proof's candidate).
        """
        model = self.model
        n2, m, p = 2 * model.n, model.m, model.p
        x_hat_a = real_vector("x_hat", x_hat, n2)
        e_hat = float(e_hat)
        if not np.isfinite(e_hat) or e_hat < 0:
            raise InvalidValueError(f"e_hat must be a finite nonnegative number, got {e_hat}")
        if warm is not None:
            if np.shape(warm) != (self.N, m):
                raise DimensionError(f"warm has shape {np.shape(warm)}, expected ({self.N}, {m})")
            if not np.all(np.isfinite(np.asarray(warm, dtype=np.float64))):
                raise InvalidValueError("warm contains NaN or inf")
        self.prepare(
            real_vector("x_bar", x_bar, n2),
            real_vector("u_bar", u_bar, m),
            real_vector("y0", y0, p),
            e_hat,
            x_pred=x_hat_a,
            warm=warm,
        )
        return self.feedback(x_hat_a)
