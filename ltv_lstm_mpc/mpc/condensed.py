r"""Condensed transcription: the FHOCP as a dense QP in the input deviations (real-time path).

Around the linearization :math:`(\tilde x_i, \tilde u_i)` of the core, the deviations
obey :math:`\delta x_{i+1} = A_i \delta x_i + B_i \delta u_i`, so (condensing, the
prediction matrices built by the recursion :math:`M_{i+1} = A_i M_i + B_i e_i` into
preallocated arrays)

.. math::

    \delta x_i = \Phi_i\, \delta x_0 + \Gamma_i\, \delta u, \qquad
    \min_{\delta u} \tfrac12 \delta u^\top H \delta u + (g_0 + F \delta x_0)^\top \delta u

with the tightened output rows of eq. (optimization_constraint_yub)/(ylb) (i = 1..N-1)
and the terminal set as rows in :math:`\delta u`, the input box as simple bounds, and
:math:`\delta x_0 = \hat x_k - \tilde x_0` inserted at feedback time (one matrix-vector
product per data vector).

The terminal set and cost take one of two forms, chosen by the solver:

- **exact cones** for a solver that solves second-order cones (the native ``clarabel``,
  or a cone solver through the dense adapter): the variables are
  :math:`(\delta u, t_c, t_h)`, stage N has no state weight, and the terminal term is
  :math:`t^\top P_f t` with :math:`\|c_N - \bar c\| \le t_c`,
  :math:`\|h_N - \bar h\| \le t_h`, :math:`\|P_f^{1/2} t\| \le \alpha_k`, :math:`t \ge 0`
  (the relaxation of :class:`~ltv_lstm_mpc.mpc.sparse.FHOCPSubproblem`, exact because
  :math:`P_f \ge 0` entrywise), with :math:`c_N, h_N` affine in :math:`\delta u` by the
  condensing: the same FHOCP as the sparse transcription, in fewer variables;
- **QP-only** solvers get the conservative replacement of paper notes 4, the math of
  :class:`~ltv_lstm_mpc.mpc.terminal.TerminalBoxReformulation` (box inside
  :math:`\mathcal X_f(k)`, cost bound
  :math:`(P_{11}+P_{12})\|c_N-\bar c\|^2 + (P_{22}+P_{12})\|h_N-\bar h\|^2`); its name
  is recorded in every :class:`~ltv_lstm_mpc.MPCSolution`.

The ``"soft"`` problem adds exact-penalty (L1) slacks :math:`s \ge 0` on the output rows
(:math:`\underline y - s \le y \le \overline y + s`) and :math:`s_T \ge 0` on the terminal
level (the box of level :math:`\max(\alpha_k, 0) + s_T`; with exact cones
:math:`\|P_f^{1/2} t\| \le \alpha_k + s_T`): :math:`\delta u = 0` with large
slacks is feasible, so the soft QP is feasible by construction. The slacks also get a
small quadratic weight (:attr:`CondensedTranscription.slack_regularization`), without
which the Hessian is too ill-conditioned for active-set solvers. First-order backends
(OSQP, PROXQP) can still reach their iteration limits on it (the policy then records
``"soft+shift"``): on the states of scenario 3, OSQP did on 63 of 233 infeasible instants;
DAQP and quadprog solved every one.
"""

from __future__ import annotations

import functools
import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.certificates.tightening import TighteningCertificate
from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.lstm.kernel import Trajectory
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc import compiled_condensing
from ltv_lstm_mpc.mpc.compiled_condensing import new_condensing_workspace
from ltv_lstm_mpc.mpc.compiled_prepare import prepare_condensed
from ltv_lstm_mpc.mpc.config import MPCConfig
from ltv_lstm_mpc.mpc.terminal import TerminalBoxReformulation, TerminalSet
from ltv_lstm_mpc.mpc.transcription import StepResult, TranscriptionBase
from ltv_lstm_mpc.solvers import (
    DenseCone,
    DenseQP,
    DenseSession,
    compiled_form,
    feasibility_tolerance,
    solver_info,
)

__all__ = [
    "BACKWARD_CONDENSING_RATIO",
    "BACKWARD_CONDENSING_RATIO_DIAGONAL",
    "CondensedTranscription",
    "backward_condensing",
]

#: With full stage weights, the compiled condensing forms H and g0 by the backward recursion
#: when N m exceeds this multiple of the state dimension 2n (else by the Gram matrix); see
#: ``mpc/compiled_condensing.py``. Measured (``experiments/condensing_speed.py``, backward /
#: Gram time, two runs): n = 5, m = 1: 1.03-1.05 / 0.79 / 0.59-0.60 at N = 5 / 20 / 30;
#: n = 10: 0.84-0.85 at N = 20; n = 20, m = 2: 0.86-0.87 at N = 20.
BACKWARD_CONDENSING_RATIO = 0.75
#: The same with diagonal stage weights (the default), against the rank updates on the
#: causal columns (``_hessian_causal``), which are cheaper than the Gram matrix. Measured
#: (backward / rank updates): n = 5, m = 1: 1.69 / 1.31 / 1.10 / 0.90 / 0.77 at N = 5 / 20 /
#: 30 / 40 / 50; n = 10: 1.08 at N = 50, 0.68 at 80; n = 20, m = 2: 0.90 at N = 50.
BACKWARD_CONDENSING_RATIO_DIAGONAL = 3.5


def backward_condensing(N: int, m: int, n2: int, diagonal: bool) -> bool:
    """Whether the compiled condensing forms H and g0 by the backward recursion (True) or
    by the rank updates on the causal columns (diagonal stage weights) or the Gram matrix
    (full ones): N m beyond :data:`BACKWARD_CONDENSING_RATIO_DIAGONAL` or
    :data:`BACKWARD_CONDENSING_RATIO` times the state dimension ``n2`` = 2n."""
    ratio = BACKWARD_CONDENSING_RATIO_DIAGONAL if diagonal else BACKWARD_CONDENSING_RATIO
    return N * m > ratio * n2


FloatArray = NDArray[np.float64]


class CondensedTranscription(TranscriptionBase):
    """Dense condensed QP of one linearization (see the module docstring).

    Parameters
    ----------
    model : LSTMModel
    config : MPCConfig
        ``solver`` (any registered solver: native dense sessions where the solver has
        one), ``tolerance``, ``solver_settings``, ``soft_penalty``, ``u_max``, ``N``.
    tightening : TighteningCertificate
        Gives :math:`P_f`.
    Q, R : ndarray
        Stage weights.
    kinds : tuple of str
        Problems to prepare sessions for (``"nominal"`` and the policy's).
    """

    name = "condensed"
    #: Quadratic slack weight of the soft QP, relative to max diag H (see :meth:`_data`).
    #: It only acts where slacks are nonzero (the L1 term keeps the penalty exact) and
    #: keeps H well enough conditioned for active-set solvers: at 1e-9 DAQP cycled
    #: (exit flag -2) on 14 of the 226 infeasible instants of scenario 3 (short), at 1e-6
    #: on none.
    slack_regularization = 1e-6

    def __init__(
        self,
        model: LSTMModel,
        config: MPCConfig,
        tightening: TighteningCertificate,
        Q: FloatArray,
        R: FloatArray,
        kinds: tuple[str, ...] = ("nominal",),
    ) -> None:
        n, m, p, N = model.n, model.m, model.p, config.N
        n2 = 2 * n
        self.model, self.config = model, config
        self.n, self.m, self.p, self.N = n, m, p, N
        #: Exact terminal cones (a cone solver) or the box reformulation (QP-only solvers).
        self.exact_cones = solver_info(config.solver).supports_cones
        self.reformulation = None if self.exact_cones else TerminalBoxReformulation.name
        #: The terminal set of eq. (optimization): cone rows or box (mpc/terminal.py).
        self.terminal = terminal = TerminalSet(tightening.P_f, n)
        # ---- weights: ||L' (x_i - x_bar)||^2 per stage i = 1..N (stage N: the terminal
        # bound of the box reformulation; none with exact cones, where t'P_f t is the term)
        term = np.zeros(n2) if self.exact_cones else terminal.box_weights
        self._diag_Q = bool(np.all(Q == np.diag(np.diag(Q))))  # exactly (as RobustMPC's check)
        if self._diag_Q:
            sw = np.tile(np.sqrt(np.diag(Q)), (N, 1))
            sw[N - 1] = np.sqrt(term)
            self._sw = sw[:, :, None]
        else:
            Lt = np.linalg.cholesky(Q).T
            self._Lt = np.tile(Lt, (N, 1, 1))
            self._Lt[N - 1] = np.diag(np.sqrt(term))
        self._Rblk = np.kron(np.eye(N), R)
        #: A lower bound on the smallest eigenvalue of the condensed H (a Gram matrix plus
        #: I_N (x) R): half R's, a margin for the Gram matrix's rounding; the QPs'
        #: ``hessian_floor``, from which DAQP bounds the objective and proves an infeasible
        #: QP infeasible sooner (``solvers.daqp_.objective_bound``).
        self.hessian_floor = 0.5 * float(np.linalg.eigvalsh(R).min())
        nu = N * m
        cols = n2 + nu
        self._n_out = n_out = (N - 1) * p
        self._mA = n_out + n2
        # ---- preallocated work arrays
        self._M = np.zeros((N + 1, n2, cols))
        self._M[0, :, :n2] = np.eye(n2)
        self._Maug = np.empty((N, n2, cols + 1))
        self._Maug_flat = self._Maug.reshape(N * n2, cols + 1)
        self._A_all = np.empty((self._mA, cols))
        self._rows0 = np.empty((2, self._mA))  # row bounds before inserting dx0
        self._lo0, self._up0 = self._rows0
        # [lb; lo] and [ub; up] of the nominal QP in one vector each (one violation test)
        self._low = np.empty(nu + self._mA)
        self._high = np.empty(nu + self._mA)
        self._lb, self._lo = self._low[:nu], self._low[nu:]
        self._ub, self._up = self._high[:nu], self._high[nu:]
        self._A_out_view = self._A_all[:n_out].reshape(N - 1, p, cols)
        self._lo0_view = self._lo0[:n_out].reshape(N - 1, p)
        self._up0_view = self._up0[:n_out].reshape(N - 1, p)
        self._W_y_T = np.ascontiguousarray(model.W_y.T)
        self._unit_half = terminal.unit_half_widths
        self._du_ref = np.empty((N, m))
        self._dx0 = np.empty(n2)
        self._dxu = np.empty(cols)
        self._traj: Trajectory | None = None
        self._last: dict[str, DenseQP] = {}  # the QPs solved since the last linearization
        self._alpha = 0.0
        # Compiled condensing (numba, mpc/compiled_condensing.py) when the model's kernel is
        # compiled: the same QP written in place; the numpy code of build() is its reference.
        #: The compiled condensing's buffers exist (built on a compiled kernel).
        self._has_compiled_buffers = self._compiled = model.kernel.compiled
        if self._compiled:
            self._Lt_all, self._Qs = self.stage_weights()
            # the Gram stack (input columns only), used with full stage weights only
            self._Maug_inputs = np.empty((0 if self._diag_Q else N, n2, nu + 1))
            #: H and g0 by the backward recursion (O(N n^3 + N^2 n m^2)) rather than the rank
            #: updates or the Gram matrix (O(N^3 n m^2)) when the horizon is long for the
            #: state size (measured: experiments/condensing_speed.py).
            self.backward_condensing = backward_condensing(N, m, n2, self._diag_Q)
            self._R = np.ascontiguousarray(R, dtype=np.float64)
            self._H = np.zeros((nu, nu))  # no F, E: delta x_0 enters at feedback time
            self._g0 = np.zeros(nu)
            self._A = np.zeros((self._mA, nu))
            self._b_y = np.ascontiguousarray(model.b_y)
            self._W_y = np.ascontiguousarray(model.W_y)
            self._f = np.zeros(nu)
            self._dX = np.zeros((N + 1, n2))
        self._choose_kernels()
        self.tolerance = feasibility_tolerance(config.solver, config.tolerance)
        if self.exact_cones:
            self._cone_qp = {kind: self._cone_problem(kind) for kind in kinds}
        settings: dict[str, Any] = dict(config.solver_settings)
        self._sessions = {
            kind: DenseSession(config.solver, tolerance=config.tolerance, **settings)
            for kind in kinds
        }
        # The nominal feedback as one compiled call in the core where DAQP's C entry point is
        # bound (mpc/native_feedback.py); otherwise, and for the other problems, the session.
        self._daqp_workspace: Any = None  # DAQP's buffers of the one-call feedback
        #: The buffers of the infeasibility policy of the one-call feedback on DAQP
        #: (:func:`~ltv_lstm_mpc.mpc.native_feedback.policy_feedback`), with DAQP's.
        self.fallback_workspace: Any = None
        # (`native` binds DAQP's compiled entry point at its first access: compiled kernels
        # only, so that the numpy reference never waits for a compilation)
        native = (
            self._sessions["nominal"].native
            if self.compiled and not self.exact_cones and "nominal" in self._sessions
            else None
        )
        if native is not None:
            from ltv_lstm_mpc.mpc.native_feedback import new_daqp_workspace
            from ltv_lstm_mpc.solvers.daqp_native import NO_BOUND

            self._daqp_workspace = new_daqp_workspace(
                sense=np.zeros(nu + self._mA, dtype=np.intc),  # cold working set
                z=np.empty(nu),
                lam=np.empty(nu + self._mA),  # multipliers
                problem=native.problem,
                result=native.result,
                settings=native.settings,
                work=native.work,  # (DAQP's workspace, kept for the paper QP)
                tolerance=self.tolerance,
                hessian_floor=self.hessian_floor,
                fval_bound=float(settings.get("fval_bound", NO_BOUND)),  # (the settings' own)
            )
            self.fallback_workspace = self._new_fallback_workspace(config)
            daqp_form = compiled_form(config.solver)
            self.flag_outcome = None if daqp_form is None else daqp_form.flag_outcome
        # Exact cones by SQP on DAQP as one compiled call (mpc/native_feedback.cone_feedback)
        # on the workspaces of the general path's sessions (the SQP's epigraph prediction
        # carries from one solve to the next in a workspace, so the same history gives the
        # same iterates): the nominal problem on the ``"nominal"`` session's (its constant
        # parts written by the session's set-up), the infeasibility policy's (``"paper"``,
        # ``"soft"``; None otherwise) on its session's. A failed nominal solve is not
        # repeated: its status is read from that workspace (``failure_outcome``).
        self._socp_workspace: Any = None
        self._adopted: tuple[int, int, int, float] | None = None  # (adopt_failed_solve)
        self.policy_socp_workspace: Any = None
        #: The ``"nominal"`` session's arrays (what a failed solve's status is read from:
        #: ``failure_outcome`` of :class:`~ltv_lstm_mpc.solvers.CompiledForm`).
        self.socp_arrays: dict[str, Any] | None = None
        form = compiled_form(config.solver) if self.compiled and self.exact_cones else None
        nominal = None
        if form is not None and form.socp_solve is not None and "nominal" in self._sessions:
            nominal = self._sessions["nominal"].compiled_workspace(self._cone_qp["nominal"])
        if nominal is not None:
            assert form is not None and form.failure_outcome is not None
            self._socp_workspace, self.socp_arrays = nominal
            self.failure_outcome = functools.partial(
                form.failure_outcome,
                tolerance=config.tolerance,
                settings=dict(config.solver_settings),
            )
            policy = config.infeasibility_policy
            if policy != "shift":
                compiled = self._sessions[policy].compiled_workspace(self._cone_qp[policy])
                assert compiled is not None
                self.policy_socp_workspace = compiled[0]
            self.fallback_workspace = self._new_fallback_workspace(config, cones=True)
        #: The compiled condensing's buffers for the bound trajectory (:meth:`workspace`).
        self._workspace: Any = None
        empty = np.zeros(0)
        self._qp = {
            kind: DenseQP(
                H=np.eye(nu),
                f=np.zeros(nu),
                A=np.zeros((0, nu)),
                lo=empty,
                up=empty,
                lb=self._lb,
                ub=self._ub,
                hessian_floor=self.hessian_floor,
            )
            for kind in kinds
        }

    def _cone_problem(self, kind: str) -> DenseQP:
        r"""The preallocated exact-cone QP of ``kind`` (values are written by :meth:`_cone_data`).

        Variables ``[du, t_c, t_h]`` (``"soft"``: then the output slacks and ``s_T``).
        """
        n, N, m = self.n, self.N, self.m
        nu, ns = N * m, self._n_out
        soft = kind == "soft"
        nz = nu + 2 + (ns + 1 if soft else 0)
        t = slice(nu, nu + 2)
        H = np.zeros((nz, nz))
        H[t, t] = self.terminal.P_f  # the QP objective is half the cost: 1/2 t'P_f t
        f = np.zeros(nz)
        lb = np.zeros(nz)  # slacks >= 0; t >= 0 follows from its cones (no bound rows)
        lb[t] = -np.inf
        ub = np.full(nz, np.inf)
        if soft:
            f[nu + 2 :] = 0.5 * self.config.soft_penalty
            A = np.zeros((2 * ns, nz))
            A[:ns, nu + 2 : nu + 2 + ns] = np.eye(ns)
            A[ns:, nu + 2 : nu + 2 + ns] = -np.eye(ns)
            lo = np.concatenate([np.zeros(ns), np.full(ns, -np.inf)])
            up = np.concatenate([np.full(ns, np.inf), np.zeros(ns)])
        elif kind == "paper":  # no output rows, no terminal set (the cost stays exact)
            A, lo, up = np.zeros((0, nz)), np.zeros(0), np.zeros(0)
        else:
            A, lo, up = np.zeros((ns, nz)), np.zeros(ns), np.zeros(ns)
        cone_c = DenseCone(np.zeros((n, nz)), np.zeros(n), np.eye(nz)[nu], 0.0)
        cone_h = DenseCone(np.zeros((n, nz)), np.zeros(n), np.eye(nz)[nu + 1], 0.0)
        cones = [cone_c, cone_h]
        if kind != "paper":
            F_t = np.zeros((2, nz))
            F_t[:, t] = self.terminal.square_root  # ||F_t z||^2 = t'P_f t
            e_t = np.eye(nz)[nz - 1] if soft else np.zeros(nz)  # alpha_k + s_T
            cones.append(DenseCone(F_t, np.zeros(2), e_t, 0.0))
        return DenseQP(H=H, f=f, A=A, lo=lo, up=up, lb=lb, ub=ub, cones=tuple(cones))

    def _cone_data(self, kind: str, f: FloatArray, lo: FloatArray, up: FloatArray) -> DenseQP:
        r"""Write one linearization into the exact-cone QP of ``kind``.

        ``lo``/``up`` are the condensed rows after inserting :math:`\delta x_0`: the output
        rows, then the terminal box rows, whose centre is :math:`\bar x - x_N(\delta u = 0)`.
        """
        qp = self._cone_qp[kind]
        n, nu, ns = self.n, self.N * self.m, self._n_out
        H = self._H
        qp.H[:nu, :nu] = H
        qp.f[:nu] = f
        if kind == "soft":
            reg = self.slack_regularization * float(np.max(np.diag(H)))
            np.fill_diagonal(qp.H[nu + 2 :, nu + 2 :], reg)  # slacks: view, in place
        A_out, A_T = self._A[:ns], self._A[ns:]
        if kind == "soft":
            qp.A[:ns, :nu] = A_out
            qp.A[ns:, :nu] = A_out
            qp.lo[:ns] = lo[:ns]
            qp.up[ns:] = up[:ns]
        elif kind == "nominal":
            qp.A[:, :nu] = A_out
            qp.lo[:] = lo[:ns]
            qp.up[:] = up[:ns]
        qp.lb[:nu] = self._lb
        qp.ub[:nu] = self._ub
        centre = 0.5 * (lo[ns:] + up[ns:])  # x_bar - x_N at du = 0
        cone_c, cone_h = qp.cones[0], qp.cones[1]
        cone_c.F[:, :nu] = A_T[:n]
        np.negative(centre[:n], out=cone_c.g)
        cone_h.F[:, :nu] = A_T[n:]
        np.negative(centre[n:], out=cone_h.g)
        if kind != "paper":
            qp.cones[2].f = float(self._alpha)
        return qp

    def stage_weights(self) -> tuple[FloatArray, FloatArray]:
        r"""The stage weights of the condensed cost by stage: ``(Lt, Qs)``, ``Qs[i]`` =
        :math:`L_i^\top L_i` the weight of :math:`x_{i+1}` (row N - 1: the terminal
        weight), ``Lt[i]`` its factor (N, 2n, 2n each; the compiled condensing's and the
        C export's form)."""
        Lt_all = np.stack([np.diag(row) for row in self._sw[:, :, 0]]) if self._diag_Q else self._Lt
        Lt_all = np.ascontiguousarray(Lt_all)
        return Lt_all, np.ascontiguousarray(np.matmul(Lt_all.transpose(0, 2, 1), Lt_all))

    @property
    def compiled(self) -> bool:
        """The compiled condensing (numba) is in use; else the numpy reference. Chosen when
        the transcription is built (from the model's kernel); setting False switches to
        the reference (tests compare the two)."""
        return self._compiled

    @compiled.setter
    def compiled(self, value: bool) -> None:
        self._compiled = bool(value) and self._has_compiled_buffers
        self._choose_kernels()

    def _choose_kernels(self) -> None:
        """Condensing, state insertion and expansion: the numba twins or the numpy ones."""
        if self._compiled:
            self._condense = self._condense_compiled
            self._insert = self._insert_compiled
            self._expand = self._expand_compiled
        else:
            self._condense = self._condense_numpy
            self._insert = self._insert_numpy
            self._expand = self._expand_numpy

    def _new_fallback_workspace(self, config: MPCConfig, *, cones: bool = False) -> Any:
        """The :data:`~ltv_lstm_mpc.mpc.native_feedback.FallbackWorkspace` of the one-call
        feedback's infeasibility policy on DAQP (``cones``: on ``daqp:socp``, where the
        policy's problem is its own exact-cone workspace and this holds the policy and the
        outcome only): for ``"soft"``, the QP of :meth:`_data`
        with its constant blocks written (identity and unit columns of the slacks, their
        penalty, the infinite bounds); the values of H, f, A and the bounds are written at
        each use."""
        from ltv_lstm_mpc.mpc.native_feedback import (
            POLICIES,
            new_fallback_workspace,
            placeholder_socp,
        )
        from ltv_lstm_mpc.solvers.socp_sqp import snapshot_sizes

        nu, ns, n2 = self.N * self.m, self._n_out, 2 * self.n
        policy = POLICIES.index(config.infeasibility_policy)
        soft = config.infeasibility_policy == "soft" and not cones  # (cones: its own QP)
        nz, rows = nu, 0
        if soft:
            nz, rows = nu + ns + 1, 2 * ns + 2 * n2
        H, f, A = np.zeros((nz, nz)), np.zeros(nz), np.zeros((rows, nz))
        low, high = np.zeros(nz + rows), np.zeros(nz + rows)
        if soft:
            f[nu:] = 0.5 * config.soft_penalty  # the QP objective is half the cost
            eye, unit = np.eye(ns), self._unit_half
            A[:ns, nu : nu + ns] = eye
            A[ns : 2 * ns, nu : nu + ns] = -eye
            A[2 * ns : 2 * ns + n2, nz - 1] = unit
            A[2 * ns + n2 :, nz - 1] = -unit
            low[nu:nz], high[nu:nz] = 0.0, np.inf  # s, s_T >= 0
            high[nz : nz + ns] = np.inf  # A_out du + s >= lo
            low[nz + ns : nz + 2 * ns] = -np.inf  # A_out du - s <= up
            high[nz + 2 * ns : nz + 2 * ns + n2] = np.inf
            low[nz + 2 * ns + n2 :] = -np.inf
        socp = placeholder_socp()  # (the cone workspaces: the sessions' with cones)
        real_size, int_size = 0, 0
        if cones:
            socp = self._socp_workspace
            assert self.socp_arrays is not None
            real_size, int_size = snapshot_sizes(self.socp_arrays)
        #: Where the nominal SQP fails, the copy of its workspace that its status is read
        #: from (:func:`~ltv_lstm_mpc.solvers.socp_sqp.snapshot_into`; empty without cones).
        self.failure_snapshot = (np.zeros(real_size), np.zeros(int_size, dtype=np.int64))
        return new_fallback_workspace(
            socp=socp, policy_socp=self.policy_socp_workspace or socp,
            policy=policy, ns=ns, H=H, f=f, A=A, high=high, low=low,
            sense=np.zeros(nz + rows, dtype=np.intc), z=np.zeros(nz), lam=np.zeros(nz + rows),
            regularization=float(self.slack_regularization), codes=np.zeros(5, dtype=np.int64),
            snapshot=self.failure_snapshot[0], snapshot_int=self.failure_snapshot[1],
        )  # fmt: skip

    @property
    def socp_workspace(self) -> Any:
        """The buffers of the core's one-call exact-cone feedback on ``daqp:socp`` (None
        for other solvers, without DAQP bound natively, or with the numpy condensing)."""
        return self._socp_workspace if self.compiled else None

    @property
    def daqp_workspace(self) -> Any:
        """DAQP's buffers of the core's one-call nominal feedback (None without DAQP bound
        natively, or with the numpy condensing)."""
        return self._daqp_workspace if self.compiled else None

    def workspace(self, traj: Trajectory) -> Any:
        """The :data:`~ltv_lstm_mpc.mpc.compiled_condensing.CondensingWorkspace` of the
        compiled condensing on the linearization trajectory ``traj`` (built once per
        trajectory; the core keeps one); None with the numpy condensing."""
        if not self._has_compiled_buffers:
            return None
        if self._workspace is None or traj is not self._traj:
            self._traj = traj
            self._workspace = new_condensing_workspace(
                J=traj.J, S=traj.S, M=self._M, Maug=self._Maug_inputs, Lt=self._Lt_all,
                Qs=self._Qs, R=self._R, W_y=self._W_y, b_y=self._b_y,
                unit_half=self._unit_half, H=self._H, g0=self._g0, A=self._A, lo0=self._lo0,
                up0=self._up0, lb=self._lb, ub=self._ub, dX=self._dX, f=self._f, lo=self._lo,
                up=self._up, low=self._low, high=self._high, u_max=float(self.config.u_max),
                diagonal=self._diag_Q,
            )  # fmt: skip
        return self._workspace

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
        """The core's preparation in one compiled call on the compiled kernel
        (:func:`~ltv_lstm_mpc.mpc.compiled_prepare.prepare_condensed`); False with the
        numpy condensing (the core then runs the steps and :meth:`build`). ``trajectories``:
        the core's :data:`~ltv_lstm_mpc.mpc.compiled_prepare.PrepareWorkspace`, on the
        trajectory bound by :meth:`workspace`."""
        if not self.compiled or self._workspace is None:
            return False
        self._last.clear()
        self._adopted = None
        self.scale, _ = prepare_condensed(
            trajectories, self._workspace, cand, previous_u, candidate, x0,
            reuse_tol if reuse_allowed else -1.0, x_bar, u_bar, lower, upper, float(alpha),
            self.backward_condensing,
        )  # fmt: skip
        self._alpha = alpha
        return True

    def last_problem(self, kind: str = "nominal") -> DenseQP:
        """A copy of the condensed QP ``kind`` as the session solved it at this step (the
        general feedback path; the one-call native path does not fill it).

        Raises
        ------
        InvalidValueError
            ``kind`` was not solved through the session since the last linearization.
        """
        if kind not in self._last:
            raise InvalidValueError(
                f"the {kind!r} subproblem was not solved through the session at this step "
                f"(solved: {sorted(self._last) or 'none'}; the nominal QP of the one-call "
                "native feedback is not kept: RobustMPC(..., native_feedback=False) keeps it)"
            )
        return self._last[kind].copy()

    def adopt_failed_solve(self, flag: int, sqp: int, iterations: int, seconds: float) -> None:
        """The one-call exact-cone feedback (``native_feedback.cone_feedback``) solved the
        nominal problem on the ``"nominal"`` session's workspace and its SQP failed (DAQP's
        exit flag ``flag`` at SQP iteration ``sqp``; ``iterations`` DAQP iterations in
        ``seconds``): the next :meth:`solve` of ``"nominal"`` takes that solve's outcome
        (the session's status checks on the workspace as the SQP left it) rather than
        solving the same problem again."""
        self._adopted = (int(flag), int(sqp), int(iterations), float(seconds))

    def forget_preparation(self) -> None:
        """The last preparation was solved outside (a compiled step engine): no scaling,
        no solved subproblems (:meth:`linearize_and_build` or :meth:`build` set them)."""
        self.scale = math.nan
        self._last.clear()
        self._adopted = None

    def reset(self) -> None:
        """Drop the solver workspaces' warm starts (in place where a session can: the
        one-call feedback on ``daqp:socp`` holds its workspaces)."""
        self._adopted = None
        for session in self._sessions.values():
            session.clear_state()

    # ---------------------------------------------------------------------- prepare
    def build(
        self,
        traj: Trajectory,
        x_bar: FloatArray,
        u_bar: FloatArray,
        lower: FloatArray,
        upper: FloatArray,
        alpha: float,
    ) -> None:
        """Condense the linearization in ``traj`` into H, F, g0 and the rows (no solve)."""
        self._last.clear()
        self._adopted = None
        self._traj = traj
        self._alpha = alpha
        self.scale = self._condense(traj, x_bar, u_bar, lower, upper, alpha)

    def _condense_compiled(
        self,
        traj: Trajectory,
        x_bar: FloatArray,
        u_bar: FloatArray,
        lower: FloatArray,
        upper: FloatArray,
        alpha: float,
    ) -> float:
        r""":meth:`build` in one numba call (``mpc/compiled_condensing.py``): the input part
        only, :math:`\delta x_0` enters at feedback time. Returns the violation scale."""
        return float(
            compiled_condensing.condense(
                self.workspace(traj), x_bar, u_bar, lower, upper, float(alpha),
                self.backward_condensing,
            )
        )  # fmt: skip

    def _condense_numpy(
        self,
        traj: Trajectory,
        x_bar: FloatArray,
        u_bar: FloatArray,
        lower: FloatArray,
        upper: FloatArray,
        alpha: float,
    ) -> float:
        """:meth:`build` in numpy (the reference): H, F, g0, the rows and E. Returns the
        violation scale."""
        n, N, m = self.n, self.N, self.m
        n2 = 2 * n
        S, J, M = traj.S, traj.J, self._M
        matmul = np.matmul
        for i in range(N):
            matmul(J[i, :, :n2], M[i], out=M[i + 1])
            M[i + 1, :, n2 + i * m : n2 + (i + 1) * m] = J[i, :, n2:]
        Maug = self._Maug
        if self._diag_Q:
            np.multiply(self._sw, M[1:], out=Maug[:, :, :-1])
            np.subtract(S[1:, :n2], x_bar, out=Maug[:, :, -1])
            Maug[:, :, -1] *= self._sw[:, :, 0]
        else:
            matmul(self._Lt, M[1:], out=Maug[:, :, :-1])
            matmul(self._Lt, (S[1:, :n2] - x_bar)[:, :, None], out=Maug[:, :, -1:])
        flat = self._Maug_flat
        gram = flat.T @ flat
        self._H = gram[n2:-1, n2:-1] + self._Rblk
        self._F = gram[n2:-1, :n2].copy()
        cand = S[:N, n2 : n2 + m]
        du_ref = self._du_ref
        np.subtract(cand, u_bar, out=du_ref)
        self._g0 = gram[n2:-1, -1] + self._Rblk @ du_ref.reshape(-1)
        # ---- rows: tightened outputs i = 1..N-1, then the terminal box on x_N
        A_all, lo0, up0 = self._A_all, self._lo0, self._up0
        n_out = self._n_out
        if N > 1:
            matmul(self.model.W_y, M[1:N, n:n2], out=self._A_out_view)
            y_lin = S[1:N, n:n2] @ self._W_y_T
            y_lin += self.model.b_y
            np.subtract(lower[1:], y_lin, out=self._lo0_view)
            np.subtract(upper[1:], y_lin, out=self._up0_view)
        A_all[n_out:] = M[N]
        half = self._unit_half * max(alpha, 0.0)
        centre = x_bar - S[N, :n2]
        np.subtract(centre, half, out=lo0[n_out:])
        np.add(centre, half, out=up0[n_out:])
        self._A = A_all[:, n2:].copy()
        self._E = A_all[:, :n2].copy()
        flat_cand = cand.reshape(-1)
        u_max = self.config.u_max
        np.subtract(-u_max, flat_cand, out=self._lb)
        np.subtract(u_max, flat_cand, out=self._ub)
        return 1.0 + max(u_max, float(np.abs(self._rows0).max()))

    # --------------------------------------------------------------------- feedback
    def _data(self, kind: str, f: FloatArray, lo: FloatArray, up: FloatArray) -> DenseQP:
        """The QP of ``kind`` in its preallocated DenseQP (values only change)."""
        qp = self._qp[kind]
        if kind == "nominal":
            qp.H, qp.f, qp.A, qp.lo, qp.up = self._H, f, self._A, lo, up
            return qp
        if kind == "paper":  # drop output and terminal rows (paper, Fig. 5)
            qp.H, qp.f, qp.A, qp.lo, qp.up = self._H, f, self._A[:0], lo[:0], up[:0]
            return qp
        # "soft": slacks s (one per output row) and s_T (terminal level)
        H, A = self._H, self._A
        nu, ns = H.shape[0], self._n_out
        nz = nu + ns + 1
        reg = self.slack_regularization * float(np.max(np.diag(H)))
        Hs = np.zeros((nz, nz))
        Hs[:nu, :nu] = H
        Hs[nu:, nu:] = reg * np.eye(ns + 1)
        penalty = 0.5 * self.config.soft_penalty  # the QP objective is half the cost
        fs = np.concatenate([f, np.full(ns + 1, penalty)])
        n2 = 2 * self.n
        A_out, A_T = A[:ns], A[ns:]
        eye = np.eye(ns)
        unit = self._unit_half[:, None]
        zeros_T = np.zeros((n2, ns))
        zeros_out = np.zeros((ns, 1))
        inf_out, inf_T = np.full(ns, np.inf), np.full(n2, np.inf)
        # A du + s >= lo, A du - s <= up, A_T du + unit s_T >= lo_T, A_T du - unit s_T <= up_T
        As = np.vstack(
            [
                np.hstack([A_out, eye, zeros_out]),
                np.hstack([A_out, -eye, zeros_out]),
                np.hstack([A_T, zeros_T, unit]),
                np.hstack([A_T, zeros_T, -unit]),
            ]
        )
        qp.H, qp.f, qp.A = Hs, fs, np.ascontiguousarray(As)
        qp.hessian_floor = min(self.hessian_floor, reg)  # (its slacks are unbounded above)
        qp.lo = np.concatenate([lo[:ns], -inf_out, lo[ns:], -inf_T])
        qp.up = np.concatenate([inf_out, up[:ns], inf_T, up[ns:]])
        qp.lb = np.concatenate([self._lb, np.zeros(ns + 1)])
        qp.ub = np.concatenate([self._ub, np.full(ns + 1, np.inf)])
        return qp

    def solve(self, kind: str, x_hat: FloatArray) -> StepResult:
        r"""Insert :math:`\delta x_0 = \hat x_k - \tilde x_0` and solve the QP ``kind``."""
        traj = self._traj
        if traj is None:  # pragma: no cover - the core always builds first
            raise RuntimeError("CondensedTranscription.solve() before build()")
        f, lo, up = self._insert(traj, x_hat)
        exact = self.exact_cones
        qp = self._cone_data(kind, f, lo, up) if exact else self._data(kind, f, lo, up)
        self._last[kind] = qp
        start = time.perf_counter()
        adopted, self._adopted = self._adopted, None
        if adopted is not None and kind == "nominal":  # the one-call feedback's failed solve
            flag, sqp, iterations, seconds = adopted
            status, z, iterations, info = self._sessions[kind].adopt_point(
                qp, flag, sqp, iterations
            )
            elapsed = seconds + time.perf_counter() - start
        else:
            status, z, iterations, info = self._sessions[kind].solve_point(qp)
            elapsed = time.perf_counter() - start
        if z is None or not status.has_solution:
            return StepResult(
                status=status,
                u=None,
                x_linear=None,
                violation=float("nan"),
                tolerance=self.tolerance,
                solver_time=elapsed,
                iterations=iterations,
                info=info,
            )
        u, x_linear, violation = self._expand(traj, kind, qp, z)
        return StepResult(
            status=status,
            u=u,
            x_linear=x_linear,
            violation=violation,
            tolerance=self.tolerance,
            solver_time=elapsed,
            iterations=iterations,
            info=info,
        )

    def _insert_compiled(
        self, traj: Trajectory, x_hat: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        r"""(f, lo, up) for :math:`\delta x_0 = \hat x_k - \tilde x_0`, propagated in one
        numba call (not condensed in the preparation)."""
        compiled_condensing.insert_state(self.workspace(traj), x_hat)
        return self._f, self._lo, self._up

    def _insert_numpy(
        self, traj: Trajectory, x_hat: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        r"""(f, lo, up) for :math:`\delta x_0` by the condensed F and E (the reference)."""
        dx0 = self._dx0
        np.subtract(x_hat, traj.S[0, : 2 * self.n], out=dx0)
        f = self._F @ dx0
        f += self._g0
        shift = self._E @ dx0
        lo = np.subtract(self._lo0, shift, out=self._lo)
        up = np.subtract(self._up0, shift, out=self._up)
        return f, lo, up

    def _expand_compiled(
        self, traj: Trajectory, kind: str, qp: DenseQP, z: FloatArray
    ) -> tuple[FloatArray, FloatArray, float]:
        """(u, x_linear, scaled violation) of the QP point ``z``, in one numba call."""
        n2, N, m = 2 * self.n, self.N, self.m
        x_linear = np.empty((N + 1, n2))
        u = np.empty((N, m))
        nu = N * m
        exact = self.exact_cones
        rows = nu if kind == "soft" or exact else nu + qp.A.shape[0]
        violation = compiled_condensing.expand_point(self.workspace(traj), z, rows, x_linear, u)
        if kind == "soft" or exact:  # slacks or cones: the QP's own rows and cones
            violation = qp.max_violation(z)
        return u, x_linear, max(violation, 0.0) / self.scale

    def _expand_numpy(
        self, traj: Trajectory, kind: str, qp: DenseQP, z: FloatArray
    ) -> tuple[FloatArray, FloatArray, float]:
        """(u, x_linear, scaled violation) of the QP point ``z`` (the reference)."""
        n2, N, m = 2 * self.n, self.N, self.m
        S = traj.S
        nu = N * m
        violation = qp.max_violation(z) / self.scale
        dxu = self._dxu
        dxu[:n2] = self._dx0
        dxu[n2:] = z[:nu]
        x_linear = self._M @ dxu
        x_linear += S[:, :n2]
        return S[:N, n2 : n2 + m] + dxu[n2:].reshape(N, m), x_linear, violation
