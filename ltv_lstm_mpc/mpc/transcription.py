r"""How the FHOCP of eq. (optimization) becomes a solver problem: the transcription interface.

The RTI core (:class:`~ltv_lstm_mpc.RobustMPC`) owns everything that is the same
for every transcription: the candidate, its rollout and linearization on the one LSTM
kernel, the tightened bounds and :math:`\alpha_k`, the prechecks, the fallback chain, the
validation of every solution, the re-simulation, the cost and the residuals. A
transcription only turns one linearization into solver data and solves it:

``"condensed"`` (:class:`~ltv_lstm_mpc.mpc.condensed.CondensedTranscription`)
    dense QP in the input deviations, prediction matrices built by the recursion into
    preallocated arrays, solved by a :class:`~ltv_lstm_mpc.solvers.DenseSession` (the
    real-time path). QP-only: the terminal cones get the conservative
    :class:`~ltv_lstm_mpc.mpc.terminal.TerminalBoxReformulation` math.
``"sparse"`` (:class:`~ltv_lstm_mpc.mpc.sparse.SparseTranscription`)
    states and inputs as variables with the exact second-order cones
    (:class:`~ltv_lstm_mpc.mpc.sparse.FHOCPSubproblem`), solved by a
    :class:`~ltv_lstm_mpc.solvers.Session` (cvxpy for cone solvers; QP-only backends get
    the named reformulation).
``"nonlinear"`` (:class:`~ltv_lstm_mpc.mpc.nmpc.NonlinearTranscription`)
    the exact NLP through CasADi + IPOPT (the accuracy reference).

Every transcription solves three kinds of problem: ``"nominal"`` (all constraints),
``"paper"`` (no output and terminal constraints, the paper's Fig. 5 fallback) and
``"soft"`` (exact-penalty slacks on the output rows and the terminal level).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.exceptions import InvalidValueError, LtvMpcError
from ltv_lstm_mpc.lstm.kernel import Trajectory
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.solvers import SolverStatus
from ltv_lstm_mpc.validation import expect_instance

__all__ = ["KINDS", "NLP_SOLVERS", "StepResult", "TranscriptionBase", "resolve_transcription"]

FloatArray = NDArray[np.float64]

#: The problems every transcription solves.
KINDS = ("nominal", "paper", "soft")


@dataclass
class StepResult:
    """One solve of a transcription, before the core validates it.

    Attributes
    ----------
    status : SolverStatus
        The backend's status, mapped through its table.
    u : ndarray (N, m) or None
        Absolute planned inputs (not clipped).
    x_linear : ndarray (N + 1, 2n) or None
        States predicted by the linearized (or nonlinear) problem.
    violation : float
        Largest violation of the solver problem's own constraints at the returned point
        (absolute, scaled by ``1 + |bound|``), computed by the transcription.
    tolerance : float
        Violation accepted for this solver
        (:func:`~ltv_lstm_mpc.solvers.feasibility_tolerance`).
    solver_time : float
        Time inside the solver call(s), s.
    iterations : int
        Solver iterations.
    info : str
        The solver's message.
    """

    status: SolverStatus
    u: FloatArray | None
    x_linear: FloatArray | None
    violation: float
    tolerance: float
    solver_time: float
    iterations: int
    info: str = ""


class TranscriptionBase(abc.ABC):
    """One linearization (or the NLP) of the FHOCP in a solver's form; see the module doc."""

    #: ``"condensed"``, ``"sparse"`` or ``"nonlinear"``.
    name: ClassVar[str]
    #: Name of the conservative cone reformulation applied, or None (exact cones).
    reformulation: str | None = None
    #: Scale of the row violations of the last build (used by the one-call feedback).
    scale: float = 1.0
    #: The acceptance tolerance of a subproblem's point
    #: (:func:`~ltv_lstm_mpc.solvers.feasibility_tolerance` of the solver).
    tolerance: float = 0.0
    #: DAQP's buffers of the core's one-call nominal feedback
    #: (:data:`~ltv_lstm_mpc.mpc.native_feedback.DaqpWorkspace`) where the transcription has
    #: one (the condensed QP with DAQP bound natively), else None.
    daqp_workspace: Any = None
    #: The buffers of the core's one-call exact-cone feedback
    #: (:data:`~ltv_lstm_mpc.solvers.socp_sqp.SocpWorkspace`) where the transcription has
    #: one (the condensed exact-cone QP on ``daqp:socp``), else None.
    socp_workspace: Any = None
    #: The buffers of the infeasibility policy of the one-call feedback on DAQP
    #: (:data:`~ltv_lstm_mpc.mpc.native_feedback.FallbackWorkspace`), with
    #: ``daqp_workspace``; else None.
    fallback_workspace: Any = None
    #: What the solver reports for a DAQP exit flag the one-call feedback recorded
    #: (``flag_outcome`` of :class:`~ltv_lstm_mpc.solvers.CompiledForm`), with ``daqp_workspace``.
    flag_outcome: Any = None
    #: With ``socp_workspace``: ``failure_outcome(snapshot, flag, sqp) -> (SolverStatus,
    #: info)``, what the session reports for a failed exact-cone solve, from a copy of the
    #: arrays of ``socp_arrays`` taken right after it.
    failure_outcome: Any = None
    #: With ``socp_workspace``: its arrays by name.
    socp_arrays: Any = None
    #: With ``socp_workspace``: the flat arrays ``(real, integer)`` that the one-call
    #: feedback copies a failed solve's ``socp_arrays`` into
    #: (:func:`~ltv_lstm_mpc.solvers.socp_sqp.snapshot_into`).
    failure_snapshot: Any = None
    #: With ``socp_workspace``: the exact-cone workspace of the infeasibility policy (None
    #: for ``"shift"``).
    policy_socp_workspace: Any = None

    @abc.abstractmethod
    def build(
        self,
        traj: Trajectory,
        x_bar: FloatArray,
        u_bar: FloatArray,
        lower: FloatArray,
        upper: FloatArray,
        alpha: float,
    ) -> None:
        r"""Preparation phase: solver data for the linearization stored in ``traj``.

        ``traj.S`` holds the candidate rollout :math:`(\tilde x_i, \tilde u_i)`, i = 0..N,
        and ``traj.J`` the Jacobians :math:`[A_i\; B_i]`; ``lower``/``upper`` (N, p) are the
        tightened output bounds and ``alpha`` is :math:`\alpha_k`.
        """

    def workspace(self, traj: Trajectory) -> Any:
        """The compiled buffers of the transcription on the linearization trajectory
        ``traj`` (the condensed QP's
        :data:`~ltv_lstm_mpc.mpc.compiled_condensing.CondensingWorkspace`), or None where
        the transcription has no compiled path."""
        return None

    def linearize_and_build(
        self,
        trajectories: Any,
        cand: FloatArray,
        previous_u: FloatArray,
        candidate: int,
        x0: FloatArray,
        reuse_allowed: bool,
        reuse_tol: float,
        x_bar: FloatArray,
        u_bar: FloatArray,
        lower: FloatArray,
        upper: FloatArray,
        alpha: float,
    ) -> bool:
        """The core's preparation (candidate, reuse of the plan's re-simulation, rollout,
        Jacobians, :meth:`build`) in one compiled call, where the transcription has one
        (:func:`~ltv_lstm_mpc.mpc.compiled_prepare.prepare_condensed`; ``trajectories`` is
        the core's :data:`~ltv_lstm_mpc.mpc.compiled_prepare.PrepareWorkspace`). Returns
        whether it did; by default it has none and the core runs these steps in Python."""
        return False

    @abc.abstractmethod
    def solve(self, kind: str, x_hat: FloatArray) -> StepResult:
        r"""Feedback phase: insert :math:`\hat x_k` and solve the problem ``kind``."""

    def last_problem(self, kind: str = "nominal") -> Any:
        """The subproblem ``kind`` as the backend got it at the last step (replay tools);
        the sparse and condensed transcriptions keep it, this one has none.

        Raises
        ------
        InvalidValueError
            Always here (the nonlinear transcription solves an NLP, not a convex problem).
        """
        raise InvalidValueError(
            f"last_problem() needs the sparse or condensed transcription; this one is {self.name!r}"
        )

    def adopt_failed_solve(self, flag: int, sqp: int, iterations: int, seconds: float) -> None:
        """The one-call exact-cone feedback's nominal SQP failed on this transcription's
        workspace: the next nominal :meth:`solve` takes its outcome (the condensed
        transcription, which has that feedback, overrides this).

        Raises
        ------
        LtvMpcError
            Always here: no one-call exact-cone feedback runs on this transcription.
        """
        raise LtvMpcError(
            f"the {self.name!r} transcription has no one-call exact-cone feedback whose "
            f"solve it could adopt (exit flag {flag} at SQP iteration {sqp})"
        )

    def reset(self) -> None:  # noqa: B027 - optional hook
        """Forget warm starts (a new closed loop begins)."""

    def forget_preparation(self) -> None:  # noqa: B027 - optional hook
        """The last preparation was solved outside this object (a compiled step engine):
        drop what it left for :meth:`solve` (the next preparation sets it again)."""


#: Solver names of the nonlinear transcription (CasADi + IPOPT).
NLP_SOLVERS = ("ipopt", "nmpc:ipopt")


def resolve_transcription(config: MPCConfig) -> str:
    """The transcription ``config`` asks for, checked against its solver and fields.

    ``"auto"``: ``"nonlinear"`` for IPOPT, ``"sparse"`` for cvxpy's solvers (cones
    included), ``"condensed"`` for every other solver: QP-only ones (terminal box
    reformulation) and the native cone solver ``clarabel`` (exact cones).

    Raises
    ------
    SolverNotFound
        ``config.solver`` is not installed.
    InvalidValueError
        A field the chosen transcription cannot honour (the message names it).
    """
    from ltv_lstm_mpc.solvers import solver_info

    config = expect_instance(
        "config", config, MPCConfig, "build one with MPCConfig(...)", expected="an MPCConfig"
    )
    chosen = config.transcription
    if config.solver in NLP_SOLVERS:
        if chosen not in ("auto", "nonlinear"):
            raise InvalidValueError(
                f"MPCConfig.transcription={chosen!r} does not fit solver={config.solver!r}: "
                "IPOPT solves the nonlinear transcription; use transcription='nonlinear' "
                "(or 'auto'), or a QP/cone solver"
            )
        chosen = "nonlinear"
    elif chosen == "nonlinear":
        raise InvalidValueError(
            f"MPCConfig.transcription='nonlinear' needs solver='ipopt', got "
            f"solver={config.solver!r}"
        )
    else:
        info = solver_info(config.solver)  # SolverNotFound names the installed ones
        if chosen == "auto":
            sparse = config.solver.startswith("cvxpy:") or (
                info.supports_cones and not info.native_dense
            )
            chosen = "sparse" if sparse else "condensed"
    if chosen == "nonlinear" and config.sqp_iterations != 1:
        raise InvalidValueError(
            f"MPCConfig.sqp_iterations={config.sqp_iterations} has no meaning for the "
            "nonlinear transcription (IPOPT solves the NLP to convergence); use 1"
        )
    return chosen
