"""Random test problems (QPs/SOCPs, MPC-shaped, dense QPs) and fault injection.

Every generator builds a strictly feasible point first and derives the
constraints around it, so the problems are feasible by construction, and a
linear cost pulls the optimum away from it, so constraints are active.

:func:`faulty` registers a wrapper of an installed solver that misbehaves on
chosen calls (NaN or garbage points reported optimal, exceptions, spurious
infeasibility), to test a caller's failure handling.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Mapping
from typing import Any, ClassVar, TypeVar

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from ltv_lstm_mpc.exceptions import InvalidValueError

from ._base import Backend, RawResult, WarmStart
from .dense import DenseBackend, DenseCone, DenseQP
from .problem import ConvexProblem, SecondOrderCone, SolverStatus

__all__ = [
    "FAULTS",
    "PREDICTED_EPIGRAPH_KINDS",
    "REDUCTION_SCALE_CASES",
    "SOCP_KINDS",
    "MpcLayout",
    "apex_socp",
    "badly_scaled_epigraph_socp",
    "controller_socp",
    "epigraph_socp",
    "faulty",
    "infeasible_dense_qp",
    "infeasible_problem",
    "perturb",
    "predicted_epigraph_socp",
    "random_dense_qp",
    "random_mpc_problem",
    "random_qp",
    "random_socp",
    "write_reduction_case",
]

FloatArray = npt.NDArray[np.float64]


def _spd(rng: np.random.Generator, n: int, cond: float = 10.0) -> FloatArray:
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    w = np.geomspace(1.0, cond, n)
    return (Q * w) @ Q.T


def random_qp(
    n: int = 10, m: int = 8, p: int = 3, *, seed: int = 0, bounds: bool = True
) -> ConvexProblem:
    """Random strictly convex feasible QP with equalities, two-sided rows and bounds.

    Some ``l``/``u``/``lb``/``ub`` entries are infinite (one-sided rows).
    """
    rng = np.random.default_rng(seed)
    z0 = rng.uniform(-1.0, 1.0, n)
    P = _spd(rng, n)
    q = rng.standard_normal(n) * 10.0
    A = rng.standard_normal((p, n)) if p else None
    b = A @ z0 if A is not None else None
    G = rng.standard_normal((m, n))
    Gz = G @ z0
    lo = Gz - rng.uniform(0.1, 1.0, m)
    hi = Gz + rng.uniform(0.1, 1.0, m)
    lo[::3] = -np.inf
    hi[1::4] = np.inf
    lb = ub = None
    if bounds:
        lb = z0 - rng.uniform(0.2, 1.0, n)
        ub = z0 + rng.uniform(0.2, 1.0, n)
        lb[::4] = -np.inf
        ub[2::5] = np.inf
    return ConvexProblem(P=P, q=q, A_eq=A, b_eq=b, G=G, l=lo, u=hi, lb=lb, ub=ub)


def random_socp(
    n: int = 10, m: int = 6, p: int = 2, n_cones: int = 2, *, seed: int = 0
) -> ConvexProblem:
    """Random feasible QP with ``n_cones`` second-order cones (strictly feasible point inside)."""
    base = random_qp(n, m, p, seed=seed, bounds=True)
    rng = np.random.default_rng(seed + 10_000)
    # the same z0 as random_qp (first draw of its generator)
    z0 = np.random.default_rng(seed).uniform(-1.0, 1.0, n)
    cones = []
    for _ in range(n_cones):
        k = int(rng.integers(2, 5))
        F = rng.standard_normal((k, n))
        g = rng.standard_normal(k)
        e = rng.standard_normal(n) * 0.1
        margin = rng.uniform(0.2, 0.5)
        f = float(np.linalg.norm(F @ z0 + g) - e @ z0 + margin)
        cones.append(SecondOrderCone(F=F, g=g, e=e, f=f))
    return base.with_values(cones=tuple(cones))


def infeasible_problem(n: int = 6, *, seed: int = 0, cone: bool = False) -> ConvexProblem:
    """QP (or SOCP) whose rows ``z_0 + z_1 >= 1`` and ``z_0 + z_1 <= -1`` contradict."""
    rng = np.random.default_rng(seed)
    G = np.zeros((2, n))
    G[:, :2] = 1.0
    cones: tuple[SecondOrderCone, ...] = ()
    if cone:
        cones = (SecondOrderCone(F=np.eye(n)[:2], g=np.zeros(2), e=np.zeros(n), f=10.0),)
    return ConvexProblem(
        P=_spd(rng, n),
        q=rng.standard_normal(n),
        G=G,
        l=np.array([1.0, -np.inf]),
        u=np.array([np.inf, -1.0]),
        lb=np.full(n, -10.0),
        ub=np.full(n, 10.0),
        cones=cones,
    )


def epigraph_socp(problem: ConvexProblem) -> ConvexProblem:
    r"""The QP ``problem`` as a second-order-cone problem: its objective's epigraph as one cone.

    The construction qpsolvers uses to hand a QP to ECOS: with :math:`P = L L^\top`
    (here from the eigendecomposition, so a singular :math:`P` is allowed: its zero
    eigenvalues are dropped) and a new last variable :math:`t`,

    .. math::

        \min_{x, t}\; t \quad\text{s.t. the rows and bounds of the QP and}\quad
        \left\| \begin{pmatrix} L^\top x \\ t - q^\top x - \tfrac12 \end{pmatrix}
        \right\| \le t - q^\top x + \tfrac12,

    the cone being :math:`\tfrac12 x^\top P x + q^\top x \le t` (squared: :math:`\|L^\top
    x\|^2 \le 2 (t - q^\top x)`). The SOCP has no quadratic term: all its curvature is in
    the cone. It is solvable, infeasible or unbounded as the QP is, with solution
    :math:`(x^*, \tfrac12 x^{*\top} P x^* + q^\top x^*)`.
    """
    n = problem.n_variables
    P = problem.P.toarray() if sp.issparse(problem.P) else np.asarray(problem.P, dtype=np.float64)
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    keep = w > 1e-12 * max(1.0, float(w.max(initial=0.0)))
    L = V[:, keep] * np.sqrt(w[keep])
    q = np.asarray(problem.q, dtype=np.float64)
    k = L.shape[1]
    F = np.zeros((k + 1, n + 1))
    F[:k, :n] = L.T
    F[k, :n] = -q
    F[k, n] = 1.0
    g = np.zeros(k + 1)
    g[k] = -0.5
    e = np.zeros(n + 1)
    e[:n] = -q
    e[n] = 1.0

    def pad(M: Any) -> sp.csc_matrix | None:
        if M is None:
            return None
        return sp.csc_matrix(sp.hstack([sp.csc_matrix(M), sp.csc_matrix((M.shape[0], 1))]))

    cost = np.zeros(n + 1)
    cost[n] = 1.0
    return ConvexProblem(
        P=sp.csc_matrix((n + 1, n + 1)),
        q=cost,
        A_eq=pad(problem.A_eq),
        b_eq=problem.b_eq,
        G=pad(problem.G),
        l=problem.l,
        u=problem.u,
        lb=None if problem.lb is None else np.append(problem.lb, -np.inf),
        ub=None if problem.ub is None else np.append(problem.ub, np.inf),
        cones=(SecondOrderCone(F=F, g=g, e=e, f=0.5),),
    )


def perturb(problem: ConvexProblem, scale: float = 1e-2, *, seed: int = 0) -> ConvexProblem:
    """Same structure, values of ``q`` and of the finite bounds changed by ``scale`` (relative).

    Used for warm-start tests (a small change between consecutive RTI steps).
    """
    rng = np.random.default_rng(seed)
    q = np.asarray(problem.q) * (1.0 + scale * rng.standard_normal(problem.n_variables))
    values: dict[str, FloatArray] = {"q": q}
    if problem.b_eq is not None:
        values["b_eq"] = np.asarray(problem.b_eq) + scale * rng.standard_normal(problem.n_eq)
    return problem.with_values(**values)


class MpcLayout:
    """Index layout of :func:`random_mpc_problem`'s variable ``z = (x_0..x_N, u_0..u_{N-1}, t)``."""

    def __init__(self, N: int, nx: int, nu: int, terminal_cone: bool) -> None:
        self.N, self.nx, self.nu = N, nx, nu
        self.n_x = (N + 1) * nx
        self.n_u = N * nu
        self.n_t = 2 if terminal_cone else 0
        self.n = self.n_x + self.n_u + self.n_t

    def x(self, i: int) -> slice:
        """Slice of ``x_i`` in ``z``."""
        return slice(i * self.nx, (i + 1) * self.nx)

    def u(self, i: int) -> slice:
        """Slice of ``u_i`` in ``z``."""
        return slice(self.n_x + i * self.nu, self.n_x + (i + 1) * self.nu)

    @property
    def t(self) -> slice:
        """Slice of ``t = (t_c, t_h)`` in ``z`` (empty without terminal cone)."""
        return slice(self.n_x + self.n_u, self.n)


def random_mpc_problem(
    N: int, nx: int = 10, nu: int = 1, *, seed: int = 0, terminal_cone: bool = True
) -> ConvexProblem:
    """MPC-shaped subproblem of paper notes section 4 in the sparse (state + input) form.

    Variables ``z = (x_0, ..., x_N, u_0, ..., u_{N-1}, t_c, t_h)``:

    - block-banded LTV dynamics equalities ``x_0 = x_init``,
      ``x_{i+1} = A_i x_i + B_i u_i + c_i`` (``A_i`` with spectral norm 0.95);
    - input box ``|u_i| <= 1`` (variable bounds), ``t >= 0``;
    - output bounds ``|C x_i| <= y_max`` (rows of ``G``);
    - terminal cones (``x_N = (c_N, h_N)`` split in halves like an LSTM state)
      ``||c_N - c_bar|| <= t_c``, ``||h_N - h_bar|| <= t_h``,
      ``||P_f^{1/2} t|| <= alpha`` and terminal cost ``t' P_f t``;
      without ``terminal_cone`` there are no cones and no ``t``;
    - cost ``sum_{i=0}^{N} (x_i - x_ref)' Q (x_i - x_ref) + sum_i u_i' R u_i``
      (positive definite Hessian, as dense active-set solvers need), ``x_ref``
      beyond the constraints so that some of them are active.

    A nominal trajectory under random inputs with ``|u| <= 0.5`` is strictly
    feasible, also for :class:`PolyhedralInnerApproximation` of the cones.

    Parameters
    ----------
    N : int
        Horizon (``>= 1``).
    nx, nu : int
        State and input dimensions (``nx >= 2``).
    seed : int
    terminal_cone : bool
    """
    if N < 1 or nx < 2 or nu < 1:
        raise InvalidValueError(f"need N >= 1, nx >= 2, nu >= 1; got N={N}, nx={nx}, nu={nu}")
    rng = np.random.default_rng(seed)
    lay = MpcLayout(N, nx, nu, terminal_cone)
    n = lay.n
    A_list = []
    for _ in range(N):
        A = rng.standard_normal((nx, nx))
        A_list.append(0.95 * A / np.linalg.norm(A, 2))
    B_list = [rng.standard_normal((nx, nu)) for _ in range(N)]
    c_list = [0.1 * rng.standard_normal(nx) for _ in range(N)]
    x_init = rng.standard_normal(nx)
    C = rng.standard_normal(nx) / math.sqrt(nx)

    # nominal (strictly feasible) trajectory
    u_nom = rng.uniform(-0.5, 0.5, (N, nu))
    x_nom = [x_init]
    for i in range(N):
        x_nom.append(A_list[i] @ x_nom[i] + B_list[i] @ u_nom[i] + c_list[i])

    # dynamics: rows block i (0..N): x_0 = x_init; x_{i+1} - A_i x_i - B_i u_i = c_i
    rows, cols, vals = [], [], []

    def add_block(r0: int, c0: int, M: FloatArray) -> None:
        rr, cc = np.meshgrid(np.arange(M.shape[0]), np.arange(M.shape[1]), indexing="ij")
        rows.append((r0 + rr).ravel())
        cols.append((c0 + cc).ravel())
        vals.append(M.ravel())

    add_block(0, 0, np.eye(nx))
    for i in range(N):
        r0 = (i + 1) * nx
        add_block(r0, lay.x(i + 1).start, np.eye(nx))
        add_block(r0, lay.x(i).start, -A_list[i])
        add_block(r0, lay.u(i).start, -B_list[i])
    A_eq = sp.csc_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=((N + 1) * nx, n),
    )
    b_eq = np.concatenate([x_init, *c_list])

    # output bounds on y_i = C x_i, i = 1..N
    y_nom = np.array([C @ x_nom[i] for i in range(1, N + 1)])
    y_max = float(np.max(np.abs(y_nom))) * 1.2 + 0.1
    G = sp.csc_matrix(
        (
            np.tile(C, N),
            (
                np.repeat(np.arange(N), nx),
                np.concatenate([np.arange(lay.x(i).start, lay.x(i).stop) for i in range(1, N + 1)]),
            ),
        ),
        shape=(N, n),
    )
    l_y = np.full(N, -y_max)
    u_y = np.full(N, y_max)

    lb = np.full(n, -np.inf)
    ub = np.full(n, np.inf)
    lb[lay.n_x : lay.n_x + lay.n_u] = -1.0
    ub[lay.n_x : lay.n_x + lay.n_u] = 1.0

    # cost
    Q = _spd(rng, nx, cond=10.0)
    R = np.eye(nu) * 0.1
    x_ref = 3.0 * rng.standard_normal(nx)
    blocks = [Q] * (N + 1)
    q = np.zeros(n)
    for i in range(N + 1):
        q[lay.x(i)] = -Q @ x_ref
    cones: tuple[SecondOrderCone, ...] = ()
    if terminal_cone:
        P_f = np.array([[2.0, 0.5], [0.5, 1.0]])  # >= 0 entrywise, positive definite
        blocks += [*([R] * N), P_f]
        lb[lay.t] = 0.0
        kc = nx // 2
        kh = nx - kc
        xN = x_nom[N]
        x_bar = xN + 0.3 * rng.standard_normal(nx)
        dev = xN - x_bar
        # t feasible for the inner (inf-norm) approximation with a margin
        t_nom = np.array(
            [
                math.sqrt(kc) * np.max(np.abs(dev[:kc])) * 1.2 + 0.05,
                math.sqrt(kh) * np.max(np.abs(dev[kc:])) * 1.2 + 0.05,
            ]
        )
        w, V = np.linalg.eigh(P_f)
        Pf_half = (V * np.sqrt(w)) @ V.T
        alpha = math.sqrt(2.0) * float(np.max(np.abs(Pf_half @ t_nom))) * 1.2
        ixN = np.arange(lay.x(N).start, lay.x(N).stop)
        it = np.arange(lay.t.start, lay.t.stop)
        e_c = np.zeros(n)
        e_c[it[0]] = 1.0
        e_h = np.zeros(n)
        e_h[it[1]] = 1.0
        Fc = sp.csc_matrix((np.ones(kc), (np.arange(kc), ixN[:kc])), shape=(kc, n))
        Fh = sp.csc_matrix((np.ones(kh), (np.arange(kh), ixN[kc:])), shape=(kh, n))
        Ft = sp.csc_matrix(
            (Pf_half.ravel(), (np.repeat(np.arange(2), 2), np.tile(it, 2))), shape=(2, n)
        )
        cones = (
            SecondOrderCone(F=Fc, g=-x_bar[:kc], e=e_c, f=0.0),
            SecondOrderCone(F=Fh, g=-x_bar[kc:], e=e_h, f=0.0),
            SecondOrderCone(F=Ft, g=np.zeros(2), e=np.zeros(n), f=alpha),
        )
    else:
        blocks += [R] * N
    P = sp.csc_matrix(sp.block_diag(blocks, format="csc"))
    return ConvexProblem(
        P=P, q=q, A_eq=A_eq, b_eq=b_eq, G=G, l=l_y, u=u_y, lb=lb, ub=ub, cones=cones
    )


# --------------------------------------------------------------------------------------
# dense QPs
# --------------------------------------------------------------------------------------
def random_dense_qp(
    n: int = 10,
    m_A: int = 20,
    seed: int = 0,
    *,
    cond: float = 10.0,
    bounds: bool = True,
    equalities: int = 0,
) -> DenseQP:
    """Random strictly convex feasible :class:`DenseQP` with active constraints.

    A strictly feasible ``x0`` is drawn first; rows ``lo <= A x <= up`` and
    bounds are placed around it (some one-sided, i.e. infinite), the first
    ``equalities`` rows get ``lo = up = A x0``, and the linear cost pulls the
    optimum onto the constraints.
    """
    rng = np.random.default_rng(seed)
    x0 = rng.uniform(-1.0, 1.0, n)
    H = _spd(rng, n, cond)
    H = 0.5 * (H + H.T)
    f = rng.standard_normal(n) * 10.0
    A = rng.standard_normal((m_A, n))
    Ax = A @ x0
    lo = Ax - rng.uniform(0.1, 1.0, m_A)
    up = Ax + rng.uniform(0.1, 1.0, m_A)
    lo[2::3] = -np.inf
    up[1::3] = np.inf  # never both infinite (PIQP prints a warning for such rows)
    k = min(equalities, m_A)
    lo[:k] = up[:k] = Ax[:k]
    if bounds:
        lb = x0 - rng.uniform(0.2, 1.0, n)
        ub = x0 + rng.uniform(0.2, 1.0, n)
        lb[::4] = -np.inf
        ub[2::5] = np.inf
    else:
        lb = np.full(n, -np.inf)
        ub = np.full(n, np.inf)
    return DenseQP(H=H, f=f, A=A, lo=lo, up=up, lb=lb, ub=ub)


#: The kinds of :func:`controller_socp`.
SOCP_KINDS = ("feasible", "infeasible", "unbounded")
_P_F = np.array([[2.0, 0.5], [0.5, 1.0]])  # a terminal weight: >= 0 entrywise, definite


def apex_socp(seed: int) -> DenseQP:
    r"""A feasible SOCP whose only points are at its cone's apex: :math:`\min c^\top x + t`
    s.t. :math:`\|x - a\| \le t \le 0`, :math:`|x_i| \le 5`, with :math:`\|c\| < 1`
    (random ``a``, ``c``, a Hessian of 0, 1e-3 or 1 on ``x`` and sometimes on ``t``). Its
    solution is :math:`x = a`, :math:`t = 0`, where the smoothed cone of ``daqp:socp``'s
    SQP is empty: the case that planes of the smoothed cone would call infeasible."""
    rng = np.random.default_rng(seed)
    p = int(rng.integers(1, 5))
    n = p + 1
    a = rng.standard_normal(p)
    c = rng.standard_normal(p)
    c *= rng.uniform(0.1, 0.99) / np.linalg.norm(c)
    H = np.zeros((n, n))
    H[:p, :p] = np.eye(p) * rng.choice([0.0, 1e-3, 1.0])
    if rng.random() < 0.5:
        H[p, p] = rng.uniform(0, 1)
    e = np.zeros(n)
    e[p] = 1.0
    return DenseQP(
        H=H, f=np.concatenate([c, [1.0]]), A=np.zeros((0, n)), lo=np.zeros(0), up=np.zeros(0),
        lb=np.concatenate([np.full(p, -5.0), [-np.inf]]),
        ub=np.concatenate([np.full(p, 5.0), [0.0]]),
        cones=(DenseCone(np.hstack([np.eye(p), np.zeros((p, 1))]), -a, e, 0.0),),
    )  # fmt: skip


#: Cases of the epigraph elimination's scale tests (``_reduction_proves`` in
#: :mod:`~ltv_lstm_mpc.solvers.socp_sqp`, ``sqp_reduction_proves`` in the C export), each
#: ``(name, epsilon, W_xx, W_tt, proves)`` for one eliminated cone's linearized row
#: :math:`x - \epsilon t \le 0` (:math:`t = x / \epsilon`, :math:`\tau = 1 / \epsilon`)
#: and :math:`W = \mathrm{diag}(W_{xx}, W_{tt})`: its reduced Hessian is :math:`W_{xx} +
#: \tau^2 W_{tt}`. Within scale the verdict is taken; each other case breaks one test
#: alone (REDUCTION_SCALE = 1e3, REDUCED_HESSIAN_LIMIT = 1e6): the row's entries 1e4
#: times :math:`|\gamma|` with a reduced Hessian of 1.1; the reduced Hessian 1e4 times
#: W's largest with the row's 1e2; the reduced Hessian 1.01e6, beyond the absolute limit,
#: 101 times W's largest.
REDUCTION_SCALE_CASES = (
    ("in_scale", 1e-2, 1.0, 1e-9, True),
    ("row_beyond_scale", 1e-4, 1.0, 1e-9, False),
    ("hessian_beyond_scale", 1e-2, 1.0, 1.0, False),
    ("hessian_beyond_limit", 1e-2, 1e4, 100.0, False),
)


def write_reduction_case(arrays: Any, epsilon: float, cost_x: float, cost_t: float) -> None:
    r"""The state the SQP's reduced solve leaves for a :data:`REDUCTION_SCALE_CASES` case,
    into ``arrays`` (a workspace's of :func:`~ltv_lstm_mpc.solvers.socp_sqp.socp_arrays`
    for 2 variables, no row and the one cone :math:`|x| \le \epsilon t`, or views of the
    C export's ``<prefix>_socp`` fields by the same names and shapes): W_k, the cone's
    linearized row (the subproblem's only row), its bound, the eliminated cone, tau."""
    arrays["hessian"][...] = np.diag([cost_x, cost_t])
    arrays["A_k"][0] = [1.0, -epsilon]
    arrays["bupper"][2], arrays["blower"][2] = 0.0, -np.inf
    arrays["epigraph"][0], arrays["eliminated"][0] = 1, 1
    arrays["reduced_index"][0] = 0
    arrays["tau"][0, 0] = 1.0 / epsilon


#: The kinds of :func:`predicted_epigraph_socp`: an infeasible problem, and feasible ones
#: whose reduced subproblem is infeasible, each blocked by another row on ``t``.
PREDICTED_EPIGRAPH_KINDS = ("infeasible", "lower_row", "upper_row", "cone")


def predicted_epigraph_socp(kind: str) -> DenseQP:
    r"""A two-variable SOCP, ``(x, t)``, for ``daqp:socp``'s epigraph elimination with its
    cone 0 (:math:`|x| \le t` or :math:`|x - 1| \le t`) predicted active (``first_active[0]
    = 1``, as a solve on which it binds leaves it): :math:`\min \tfrac12 (x - 2)^2 +
    \tfrac12 t^2`, :math:`x \le 10`, and, by ``kind`` (:data:`PREDICTED_EPIGRAPH_KINDS`):

    - ``"infeasible"``: :math:`|x| \le t`, :math:`x \ge -10`, the row :math:`x \ge 3` and
      the cone :math:`|t| \le 1` (the MPC's terminal set on its epigraph variables has
      this form): the subproblem without ``t`` is infeasible at SQP iteration 2, and that
      proves the whole subproblem infeasible (no other row keeps ``t`` from its cone's
      row);
    - the others: :math:`|x - 1| \le t`, :math:`x \ge -3`, feasible, the cone inactive at
      the solution; the subproblem without ``t`` (:math:`t = 1 - x` at the cold start) is
      infeasible there, a verdict on nothing, for another row keeps ``t`` from its cone's
      row: ``"lower_row"``, the row :math:`t \ge 5` (:math:`x = 2`, :math:`t = 5`);
      ``"upper_row"``, the row :math:`-t \le -5` (the same); ``"cone"``, the cone
      :math:`|t - 5| \le 0.5` (:math:`x = 2`, :math:`t = 4.5`)."""
    e_t = np.array([0.0, 1.0])
    A, lo, up = np.zeros((1, 2)), np.full(1, -np.inf), np.full(1, np.inf)
    x_low = -3.0
    cones: tuple[DenseCone, ...] = (DenseCone(np.array([[1.0, 0.0]]), -np.ones(1), e_t, 0.0),)
    if kind == "infeasible":
        x_cone = DenseCone(np.array([[1.0, 0.0]]), np.zeros(1), e_t, 0.0)
        t_cone = DenseCone(np.array([[0.0, 1.0]]), np.zeros(1), np.zeros(2), 1.0)
        A[0, 0], lo[0], x_low, cones = 1.0, 3.0, -10.0, (x_cone, t_cone)
    elif kind == "lower_row":
        A[0, 1], lo[0] = 1.0, 5.0
    elif kind == "upper_row":
        A[0, 1], up[0] = -1.0, -5.0
    elif kind == "cone":
        A, lo, up = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
        cones += (DenseCone(np.array([[0.0, 1.0]]), -np.full(1, 5.0), np.zeros(2), 0.5),)
    else:
        raise ValueError(f"kind {kind!r}: one of {PREDICTED_EPIGRAPH_KINDS}")
    return DenseQP(
        H=np.eye(2), f=np.array([-2.0, 0.0]), A=A, lo=lo, up=up,
        lb=np.array([x_low, -np.inf]), ub=np.array([10.0, np.inf]), cones=cones,
    )  # fmt: skip


def badly_scaled_epigraph_socp(which: int) -> DenseQP:
    r"""Two feasible SOCPs with epigraph cones whose substitution (``daqp:socp``'s epigraph
    elimination, :math:`t_j = \ldots + \tau_j^\top y`) scales the reduced QP badly, found
    by reviews of its reduced subproblem's verdict: DAQP called their feasible reduced QPs
    infeasible. ``which`` 0: 7 variables, cones :math:`\|F_j z + g_j\| \le 10^{-4} t_j`
    (and :math:`10^{-3}`) with :math:`F_j` of order 1e2 (:math:`|\tau|` about 1e6, a
    reduced Hessian of order 1e12 against 1); 1: 4 variables, cones :math:`\|F_j z +
    g_j\| \le 0.1 t_j` (0.3) with :math:`F_j` of order 1e2 and a cost of 1e6 on the
    :math:`t_j` (:math:`|\tau|` about 300-500, the reduced Hessian 1.7e12, 100 times
    :math:`W_k`'s largest entry, beyond ``REDUCED_HESSIAN_LIMIT``). The SQP converges on
    both without the elimination."""
    if which == 0:
        H = np.array([
            [4.341275886412793, -0.3863839346431118, -1.0791870356921582, 1.9361512976893152,
             -0.6010177796352326, -0.508560049805802, 1.0228527388583981],
            [-0.38638393464311177, 4.062590013964517, -0.24196789464743218, 1.4986233927143198,
             -0.14050985718891013, 1.775870222743376, -1.0827602521422257],
            [-1.079187035692158, -0.24196789464743215, 3.131969241290833, -0.604825292336469,
             0.2127257794359858, 0.3944918875257008, 1.3215677728618576],
            [1.936151297689315, 1.4986233927143195, -0.604825292336469, 4.196124339821665,
             -0.0230503619628195, 0.8380788260824943, -0.22801462614556542],
            [-0.6010177796352325, -0.1405098571889101, 0.21272577943598583, -0.02305036196281963,
             2.142638332708427, 0.143286002959758, -0.09866247513608296],
            [-0.5085600498058018, 1.775870222743376, 0.3944918875257007, 0.8380788260824943,
             0.14328600295975802, 3.9840145325333127, -0.9499910980762512],
            [1.0228527388583983, -1.082760252142226, 1.3215677728618576, -0.22801462614556528,
             -0.09866247513608296, -0.9499910980762512, 4.325166625545158],
        ])  # fmt: skip
        f = np.array([2.0255382683575904, 0.20596736558341466, -6.881399321422857,
                      6.7493152088987385, -6.401302641532486, -1.3374454321089264,
                      -9.111481263091212])  # fmt: skip
        A = np.array([[-1.0925546789095177, 0.0, -1.1135275305321823, 0.0, 1.8850671944283999,
                       0.0, 0.5628777777878765]])  # fmt: skip
        lb = np.array([-1.8257114204100409, -np.inf, -1.799788578650805, -np.inf,
                       -0.9852983300242022, -np.inf, -0.6979253303948014])  # fmt: skip
        ub = np.array([2.018435002261157, np.inf, 1.421816922015957, np.inf, 1.4490010249439587,
                       np.inf, 2.0013893861713736])  # fmt: skip
        e = np.eye(7)
        cones = [
            (np.array([[-11.203296972322335, 0.0, 22.499204177953366, 0.0, -76.21589548633601,
                        0.0, 23.827531382937636]]),
             np.array([-3.903854425637048]), 1e-4 * e[1], 0.4809573423051501),
            (np.array([[-0.02046192456205767, 0.0, -0.00831507610123121, 0.0,
                        -0.00092568568989453, 0.0, 0.01161675406034457],
                       [-0.00355621901887392, 0.0, 0.01112702979594248, 0.0,
                        -0.01629665060876534, 0.0, -0.00289604837787744]]),
             np.array([-0.08705872180555504, -0.5580490571757452]), -1e-3 * e[3],
             0.19436789634886534),
            (np.array([[0.00975864434479713, 0.0, -0.02144943083983143, 0.0, 0.01609957162896283,
                        0.0, 0.01915481348896006],
                       [0.02234234408637831, 0.0, -0.0005968210216508, 0.0,
                        -0.00704120540257469, 0.0, 0.00608226259483285]]),
             np.array([0.48111284502947893, 3.0081225166294683]), 1e-3 * e[5],
             -0.112244111796927),
            (np.array([[0.18486394906231593, -0.9744610660177727, -0.24930538593634577,
                        -0.8823820711082597, 0.10351597987261561, -0.6733700512714766,
                        -0.3520813189902169],
                       [0.32976646050136565, 0.5566169808116159, 0.21795725524487428,
                        -0.06864205484407415, -0.08050220242914514, 0.24005779911181097,
                        0.05947743431150355]]),
             np.zeros(2), np.zeros(7), 1.3851250669448494),
        ]  # fmt: skip
        lo, up = np.array([-np.inf]), np.array([3.600068287731903])
    elif which == 1:
        H = np.array([
            [1.1803088937888145e06, 4.7901493894999055e02, 7.0969165428939625e05,
             8.2771215382155741e05],
            [4.7901493894999061e02, 1.0323498374967657e00, 8.7141963233654519e02,
             -3.1114822650672740e00],
            [7.0969165428939625e05, 8.7141963233654496e02, 1.6576020468210024e06,
             -9.1056979504894163e05],
            [8.2771215382155753e05, -3.1114822650672962e00, -9.1056979504894174e05,
             2.9950687556497506e06],
        ])  # fmt: skip
        f = np.array([8.820714691083321, 6.653579634803602, -1.919804371750744,
                      6.326312176520352])  # fmt: skip
        A = np.array([[0.0, -2.062268615273777, 0.0, 0.0]])
        lo, up = np.array([-3.147710293815738]), np.array([-0.6724467710090285])
        lb = np.array([-np.inf, -2.516277873344745, -np.inf, -np.inf])
        ub = np.array([np.inf, 2.9716965126118517, np.inf, np.inf])
        e = np.eye(4)
        cones = [
            (np.array([[0.0, 44.79197734366053, 0.0, 0.0]]), np.array([-0.46722792749562414]),
             0.1 * e[0], 0.0009500722410693338),
            (np.array([[0.0, 84.53212570124016, 0.0, 0.0], [0.0, -58.97952563667348, 0.0, 0.0]]),
             np.array([-1.8730856657898025, -3.5328958826973906]), -0.3 * e[2],
             0.2390747556302376),
            (np.array([[0.0, 16.78256607999674, 0.0, 0.0], [0.0, -119.68292483950613, 0.0, 0.0],
                       [0.0, 91.35200805676763, 0.0, 0.0]]),
             np.array([-1.9625600604548907, 3.6107606694828815, 3.5424759992510473]),
             0.3 * e[3], 0.1101861495025691),
        ]  # fmt: skip
    else:
        raise ValueError(f"which {which!r}: 0 or 1")
    return DenseQP(
        H=H,
        f=f,
        A=A,
        lo=lo,
        up=up,
        lb=lb,
        ub=ub,
        cones=tuple(DenseCone(F, g, e_j, offset) for F, g, e_j, offset in cones),
    )


def controller_socp(seed: int, kind: str, linear_t: bool) -> DenseQP:
    r"""A random SOCP of the controller's exact-cone shape (``CondensedTranscription.
    _cone_data``): variables ``(du, t_c, t_h)``, boxes on ``du``, output rows and the
    cones :math:`\|F_c du + g_c\| \le t_c`, :math:`\|F_h du + g_h\| \le t_h`,
    :math:`\|P_f^{1/2} t\| \le \alpha`; ``kind`` (:data:`SOCP_KINDS`) by construction:
    ``"feasible"`` (a strictly feasible point built first), ``"infeasible"`` (the boxes keep
    :math:`\|F_c du + g_c\|` above :math:`m_c > 0` and :math:`\alpha < \sqrt{(P_f)_{11}}
    m_c`), ``"unbounded"`` (one free ``du`` entry with no curvature, a linear cost, in no
    row or cone); the terminal cost :math:`t^\top P_f t` or, with ``linear_t``, linear in
    ``t`` (the first SQP subproblem of ``daqp:socp`` is then unbounded)."""
    rng = np.random.default_rng(seed)
    p = int(rng.integers(2, 7))  # inputs over the horizon
    k = int(rng.integers(1, 4))  # rows of each state cone
    rows = int(rng.integers(0, 4))
    n = p + 2
    Q, _ = np.linalg.qr(rng.standard_normal((p, p)))
    H = np.zeros((n, n))
    H[:p, :p] = (Q * np.geomspace(0.1, 10.0, p)) @ Q.T
    f = np.zeros(n)
    f[:p] = rng.standard_normal(p) * 3.0
    if linear_t:
        f[p:] = rng.uniform(0.1, 2.0, 2)
    else:
        H[p:, p:] = _P_F
    u_max = rng.uniform(0.5, 2.0)
    lb = np.concatenate([np.full(p, -u_max), np.full(2, -np.inf)])
    ub = np.concatenate([np.full(p, u_max), np.full(2, np.inf)])
    du0 = rng.uniform(-0.5, 0.5, p) * u_max
    A = np.zeros((rows, n))
    A[:, :p] = rng.standard_normal((rows, p))
    if kind == "unbounded":  # du_0 in no row (below): the rows are centred without it
        A[:, 0] = 0.0
    center = A[:, :p] @ du0
    lo = center - rng.uniform(0.1, 1.0, rows)
    up = center + rng.uniform(0.1, 1.0, rows)
    F_c = np.zeros((k, n))
    F_h = np.zeros((k, n))
    F_c[:, :p] = rng.standard_normal((k, p))
    F_h[:, :p] = rng.standard_normal((k, p))
    g_c = rng.standard_normal(k)
    g_h = rng.standard_normal(k)
    if kind == "unbounded":  # du_0 free, flat, costed, in no row or cone
        H[0, :] = 0.0
        H[:, 0] = 0.0
        f[0] = rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 2.0)
        lb[0], ub[0] = -np.inf, np.inf
        A[:, 0] = 0.0
        F_c[:, 0] = 0.0
        F_h[:, 0] = 0.0
    if kind == "infeasible":  # the boxes keep |F_c du + g_c| >= m_c > 0
        g_c = g_c / np.linalg.norm(g_c) * (np.abs(F_c[:, :p]).sum(axis=1).max() * u_max * 2 + 1)
        m_c = np.linalg.norm(g_c) - np.linalg.norm(F_c[:, :p], 2) * u_max * np.sqrt(p)
        assert m_c > 0
        alpha = 0.9 * np.sqrt(_P_F[0, 0]) * m_c
    else:
        x0 = np.append(du0, [0.0, 0.0])
        t0 = np.array([np.linalg.norm(F_c @ x0 + g_c) + 0.1, np.linalg.norm(F_h @ x0 + g_h) + 0.1])
        w, V = np.linalg.eigh(_P_F)
        alpha = float(np.linalg.norm((V * np.sqrt(w)) @ V.T @ t0)) * rng.uniform(1.05, 2.0)
    e_c = np.zeros(n)
    e_c[p] = 1.0
    e_h = np.zeros(n)
    e_h[p + 1] = 1.0
    w, V = np.linalg.eigh(_P_F)
    F_t = np.zeros((2, n))
    F_t[:, p:] = (V * np.sqrt(w)) @ V.T
    cones = (
        DenseCone(F_c, g_c, e_c, 0.0),
        DenseCone(F_h, g_h, e_h, 0.0),
        DenseCone(F_t, np.zeros(2), np.zeros(n), float(alpha)),
    )
    return DenseQP(H=H, f=f, A=A, lo=lo, up=up, lb=lb, ub=ub, cones=cones)


def infeasible_dense_qp(n: int = 6, *, seed: int = 0) -> DenseQP:
    """Dense QP whose rows ``x_0 + x_1 >= 1`` and ``x_0 + x_1 <= -1`` contradict."""
    rng = np.random.default_rng(seed)
    A = np.zeros((2, n))
    A[:, :2] = 1.0
    return DenseQP(
        H=_spd(rng, n),
        f=rng.standard_normal(n),
        A=A,
        lo=np.array([1.0, -np.inf]),
        up=np.array([np.inf, -1.0]),
        lb=np.full(n, -10.0),
        ub=np.full(n, 10.0),
    )


# --------------------------------------------------------------------------------------
# fault injection
# --------------------------------------------------------------------------------------
#: Faults :func:`faulty` can inject.
FAULTS = ("nan", "garbage", "raise", "infeasible")
#: Entries of the point a ``"garbage"`` fault reports optimal.
GARBAGE = 1e6


class _Trigger:
    """Shared 0-based solve counter of one :func:`faulty` name and the calls that fault."""

    def __init__(self, calls: frozenset[int] | None) -> None:
        self.calls = calls
        self.count = 0

    def __call__(self) -> bool:
        k = self.count
        self.count += 1
        return self.calls is None or k in self.calls


def _fault_result(fault: str, n: int, call: int) -> RawResult:
    if fault == "raise":
        raise RuntimeError(f"injected fault 'raise' on solve call {call}")
    if fault == "infeasible":
        status, z = SolverStatus.INFEASIBLE, None
    elif fault == "nan":
        status, z = SolverStatus.OPTIMAL, np.full(n, np.nan)
    else:
        status, z = SolverStatus.OPTIMAL, np.full(n, GARBAGE)
    return RawResult(
        status=status,
        native_status=f"injected fault {fault!r}",
        z=z,
        duals=None,
        solve_time=0.0,
        iterations=0,
        notes=(f"injected fault {fault!r} on solve call {call}",),
    )


class _FaultyBackend(Backend):
    """ConvexProblem backend wrapper that injects a fault on the triggered calls.

    :func:`_mirror` makes the subclass actually used, with the capabilities (cones,
    in-place update, warm start) of the wrapped backend.
    """

    backend: ClassVar[str] = "faulty"

    def __init__(self, inner: Backend, fault: str, trigger: _Trigger) -> None:
        super().__init__(inner.name, inner.solver, inner.options)
        self._inner, self._fault, self._trigger = inner, fault, trigger
        self._n = 0

    def handles_cones(self) -> bool:
        return self._inner.handles_cones()

    def setup(self, problem: ConvexProblem) -> None:
        self._n = problem.n_variables
        self._inner.setup(problem)

    def update(self, problem: ConvexProblem) -> None:
        self._inner.update(problem)  # called only when the inner backend supports it

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        call = self._trigger.count
        if self._trigger():
            return _fault_result(self._fault, self._n, call)
        return self._inner.solve(warm_start)


class _FaultyDense(DenseBackend):
    """Dense backend wrapper that injects a fault on the triggered calls.

    Like :class:`_FaultyBackend`, used through its :func:`_mirror` subclass. It has no
    ``native`` entry point even where the wrapped backend has one: a compiled caller
    would bypass the injected faults, so the faulty name always takes the general path.
    """

    backend: ClassVar[str] = "faulty"

    def __init__(self, inner: DenseBackend, fault: str, trigger: _Trigger) -> None:
        super().__init__(inner.name, inner.solver, inner.options)
        self._inner, self._fault, self._trigger = inner, fault, trigger
        self._n = 0

    def handles_cones(self) -> bool:
        return self._inner.handles_cones()

    def setup(self, qp: DenseQP) -> None:
        self._n = qp.n_variables
        self._inner.setup(qp)

    def update(self, qp: DenseQP) -> None:
        self._inner.update(qp)  # called only when the inner backend supports it

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        call = self._trigger.count
        if self._trigger():
            return _fault_result(self._fault, self._n, call)
        return self._inner.solve(warm_start)


_Wrapper = TypeVar("_Wrapper", _FaultyBackend, _FaultyDense)


@functools.cache
def _mirror_class(
    wrapper: type[_Wrapper], supports_cones: bool, supports_update: bool, supports_warm_start: bool
) -> type[_Wrapper]:
    attrs = {
        "supports_cones": supports_cones,
        "supports_update": supports_update,
        "supports_warm_start": supports_warm_start,
    }
    return type(wrapper.__name__, (wrapper,), attrs)


def _mirror(
    wrapper: type[_Wrapper], inner: Backend | DenseBackend, fault: str, trigger: _Trigger
) -> _Wrapper:
    """A ``wrapper`` around ``inner`` with ``inner``'s capabilities: the sessions then treat
    the faulty name exactly as the backend it wraps (exact cones, in-place update, warm
    start), so every path of the base solver can be exercised with faults."""
    cls = _mirror_class(
        wrapper,
        bool(inner.supports_cones),
        bool(inner.supports_update),
        bool(inner.supports_warm_start),
    )
    return cls(inner, fault, trigger)


def faulty(base_name: str, fault: str, calls: int | Iterable[int] | None = None) -> str:
    """Register (``replace=True``) a fault-injecting wrapper of ``base_name``; return its name.

    Parameters
    ----------
    base_name : str
        Any installed solver (:func:`~ltv_lstm_mpc.solvers.available_solvers`).
    fault : str
        ``"nan"`` (an all-NaN point reported ``OPTIMAL``; sessions turn it into
        ``FAILED``), ``"garbage"`` (every entry ``1e6``, reported ``OPTIMAL``),
        ``"raise"`` (the backend raises ``RuntimeError("injected fault ...")``)
        or ``"infeasible"`` (``INFEASIBLE``, no point).
    calls : int or iterable of int, optional
        0-based indices of the solve calls that fault, counted over **all**
        sessions (:class:`~ltv_lstm_mpc.solvers.Session` and
        :class:`~ltv_lstm_mpc.solvers.DenseSession`) made from the returned
        name with one shared counter; ``None``: every call. Calling
        :func:`faulty` again with the same arguments re-registers the name
        with a fresh counter. The other calls go to the real backend.

    Returns
    -------
    str
        E.g. ``"faulty:nan@0,2:daqp"`` (``@all`` for ``calls=None``); its
        :func:`~ltv_lstm_mpc.solvers.solver_info` copies the base's capabilities, and
        its sessions keep the wrapped backend's (exact second-order cones, in-place
        update, warm start), so a faulty native cone solver (``faulty("clarabel",
        ...)``) runs the exact-cone path. A compiled entry point (DAQP's ``native``)
        is not passed on: the faults would bypass it.

    Raises
    ------
    InvalidValueError
        Unknown ``fault`` or a negative call index.
    SolverNotFound
        Unknown ``base_name``.
    """
    from .registry import _add, _Entry, get_backend, get_dense_backend, solver_info

    if fault not in FAULTS:
        raise InvalidValueError(f"unknown fault {fault!r}; choose one of {list(FAULTS)}")
    base = solver_info(base_name)
    which: frozenset[int] | None
    if calls is None:
        which, tag = None, "all"
    else:
        which = frozenset([int(calls)] if isinstance(calls, int | np.integer) else map(int, calls))
        if any(c < 0 for c in which):
            raise InvalidValueError(f"calls must be >= 0, got {sorted(which)}")
        tag = ",".join(str(c) for c in sorted(which)) or "none"
    name = f"faulty:{fault}@{tag}:{base_name}"
    trigger = _Trigger(which)
    sparse = get_backend(base_name)
    dense = get_dense_backend(base_name)

    def factory(_name: str, tolerance: float, settings: Mapping[str, Any]) -> Backend:
        return _mirror(_FaultyBackend, sparse(base_name, tolerance, settings), fault, trigger)

    def dense_factory(_name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
        return _mirror(_FaultyDense, dense(base_name, tolerance, settings), fault, trigger)

    info = type(base)(
        name=name,
        family="faulty",
        supports_cones=base.supports_cones,
        native_dense=base.native_dense,
        first_order=base.first_order,
    )
    return _add(name, _Entry(info, factory, dense_factory), replace=True)
