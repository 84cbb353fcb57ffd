"""DAQP's C entry point ``daqp_quadprog`` called from numba-compiled code (no Python per solve).

``daqp.solve`` (the Python package's one-shot call) builds three C structs and calls
``daqp_quadprog(DAQPResult*, DAQPProblem*, DAQPSettings*)``; this module makes the same call
from inside ``@njit`` functions, so that a compiled controller step can set up, solve and
read a condensed QP without returning to Python. Same C function, same settings: the same
iterates and results as ``daqp.solve``, bit for bit (``tests/test_daqp_native.py``).

How it is bound
    The DAQP symbols are exported by the extension module of the ``daqp`` package; the
    library is loaded into LLVM's symbol table (``llvmlite.binding.load_library_permanently``)
    and ``daqp_quadprog`` declared as a numba ``ExternalFunction``, so compiled callers link
    against it by name and stay cacheable on disk. The three structs are plain byte buffers
    written through integer/float views at the field offsets of :class:`_Problem`,
    :class:`_Settings` and :class:`_Result` (ctypes computes them from the field lists, which
    follow ``csrc/include/types.h`` and ``api.h`` of the DAQP release in
    :data:`BOUND_VERSIONS`, as shipped in its source distribution).

Safety
    The structs change between DAQP releases, so the binding is used only for a release in
    :data:`BOUND_VERSIONS` *and* after a self-test at first use (a small QP solved both ways
    must agree exactly, exit flag and iterations included). Otherwise :func:`native` returns
    ``None`` and :attr:`unavailable_reason` says why; callers then keep ``daqp.solve``.
"""

from __future__ import annotations

import ctypes
import importlib.metadata
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.numba_support import njit

try:  # pragma: no cover - numba is a core dependency
    from numba import types
except ImportError:  # pragma: no cover - then native() returns None (see below)
    types = None  # type: ignore[assignment]


FloatArray = NDArray[np.float64]

__all__ = [
    "ACTIVITY_MARGIN",
    "BOUND_VERSIONS",
    "CONDITION_LIMIT",
    "KEEP_FROM",
    "NO_BOUND",
    "ROUNDING_MARGIN",
    "SELF_TEST_KERNELS",
    "WORKSPACE_BYTES",
    "WORKSPACE_SETTINGS_OFFSET",
    "DaqpNative",
    "activity_infeasible",
    "bound",
    "box_quadprog_from",
    "native",
    "objective_bound",
    "primal_tolerance",
    "quadprog",
    "quadprog_kept",
    "ready",
    "release_workspace",
    "set_objective_bound",
    "solver_seconds",
    "unavailable_reason",
]

#: DAQP releases whose struct layouts the field lists below were written from.
BOUND_VERSIONS = ("0.11.0",)


class _Problem(ctypes.Structure):
    """``DAQPProblem`` (types.h): min 1/2 x'Hx + f'x, blower <= [x_(ms); A x] <= bupper."""

    _fields_ = [
        ("n", ctypes.c_int),
        ("m", ctypes.c_int),
        ("ms", ctypes.c_int),
        ("H", ctypes.c_void_p),
        ("f", ctypes.c_void_p),
        ("A", ctypes.c_void_p),
        ("bupper", ctypes.c_void_p),
        ("blower", ctypes.c_void_p),
        ("sense", ctypes.c_void_p),
        ("break_points", ctypes.c_void_p),
        ("nh", ctypes.c_int),
        ("problem_type", ctypes.c_int),
    ]


_DOUBLE, _INT = ctypes.c_double, ctypes.c_int


class _Settings(ctypes.Structure):
    """``DAQPSettings`` (types.h); field names are the ``daqp.solve`` keyword names."""

    _fields_ = [
        ("primal_tol", _DOUBLE),
        ("dual_tol", _DOUBLE),
        ("zero_tol", _DOUBLE),
        ("pivot_tol", _DOUBLE),
        ("progress_tol", _DOUBLE),
        ("cycle_tol", _INT),
        ("iter_limit", _INT),
        ("fval_bound", _DOUBLE),
        ("eps_prox", _DOUBLE),
        ("eta_prox", _DOUBLE),
        ("rho_soft", _DOUBLE),
        ("rel_subopt", _DOUBLE),
        ("abs_subopt", _DOUBLE),
        ("sing_tol", _DOUBLE),
        ("refactor_tol", _DOUBLE),
        ("time_limit", _DOUBLE),
        ("w_soft", _DOUBLE),
        ("eq_reduction", _INT),
        ("presolve", _INT),
    ]


class _Result(ctypes.Structure):
    """``DAQPResult`` (api.h)."""

    _fields_ = [
        ("x", ctypes.c_void_p),
        ("lam", ctypes.c_void_p),
        ("fval", _DOUBLE),
        ("soft_slack", _DOUBLE),
        ("exitflag", _INT),
        ("iter", _INT),
        ("nodes", _INT),
        ("solve_time", _DOUBLE),
        ("setup_time", _DOUBLE),
    ]


def _slot(struct: type[ctypes.Structure], field: str, width: int) -> int:
    """Index of ``field`` in a view of ``width``-byte items of the struct's buffer."""
    offset = getattr(struct, field).offset
    assert offset % width == 0
    return int(offset // width)


# Field slots as compile-time constants of the compiled call (8-byte and 4-byte views).
_P_N, _P_M, _P_MS = (_slot(_Problem, f, 4) for f in ("n", "m", "ms"))
_P_H, _P_F, _P_A, _P_BU, _P_BL, _P_SENSE, _P_BP = (
    _slot(_Problem, f, 8) for f in ("H", "f", "A", "bupper", "blower", "sense", "break_points")
)
_P_NH, _P_TYPE = _slot(_Problem, "nh", 4), _slot(_Problem, "problem_type", 4)
_R_X, _R_LAM = _slot(_Result, "x", 8), _slot(_Result, "lam", 8)
_R_FLAG, _R_ITER = _slot(_Result, "exitflag", 4), _slot(_Result, "iter", 4)
_R_SOLVE, _R_SETUP = _slot(_Result, "solve_time", 8), _slot(_Result, "setup_time", 8)
_S_PRIMAL, _S_FVAL = _slot(_Settings, "primal_tol", 8), _slot(_Settings, "fval_bound", 8)
_S_PROX, _S_ZERO = _slot(_Settings, "eps_prox", 8), _slot(_Settings, "zero_tol", 8)
_R_SETUP_BYTE = _Result.setup_time.offset
_EPSILON = float(np.finfo(np.float64).eps)

#: Bytes reserved for a caller-owned ``DAQPWorkspace`` (types.h of the release in
#: :data:`BOUND_VERSIONS`: 328 bytes) ...
WORKSPACE_BYTES = 512
#: ... and the byte offset of its ``settings`` pointer there (``tests/test_daqp_native.py``
#: compiles the vendored headers of that release and checks both).
WORKSPACE_SETTINGS_OFFSET = 224
_W_SETTINGS = WORKSPACE_SETTINGS_OFFSET // 8
#: The fewest variables from which a caller keeps the workspace of a QP for the next one
#: (:func:`quadprog_kept`): below it re-factoring H costs less than what a kept
#: workspace adds where the next QP's unconstrained optimum holds (a fresh solve after
#: the kept one); measured by ``experiments/daqp_kept_workspace.py``.
KEEP_FROM = 20
# DAQP's update masks (constants.h): the working set; the unconstrained check; the
# elimination of equality rows (daqp_quadprog's set-up asks for the last two)
_UPDATE_SENSE, _UPDATE_UNCONSTRAINED, _UPDATE_ELIMINATE = 16, 64, 128
#: :func:`objective_bound` is given only where DAQP provably factors H as it is (no
#: proximal regularization): n eps tr(H) at most this times the floor (DAQP regularizes
#: where n eps cond(H) > 0.1, ``DAQP_HESSIAN_COND_EPS``; a margin of 100)...
ROUNDING_MARGIN = 1e-3
#: ... and tr(H) at most this times the floor (DAQP's limit with equality elimination is
#: 1e8, ``DAQP_HESSIAN_COND_MAX``: a margin of 10 for the rounding of its test).
CONDITION_LIMIT = 1e7

#: DAQP's "no bound" (``DAQP_INF`` of its headers): the ``fval_bound`` of its default settings.
NO_BOUND = 1e30
#: The rounding margin of :func:`activity_infeasible`, relative to the magnitudes of a
#: row's terms and bound (their sum's rounding error is below n eps of them).
ACTIVITY_MARGIN = 1e-9

unavailable_reason = ""
_LOADED = False
_daqp_quadprog: Any = None
_setup_daqp_main: Any = None
_daqp_solve: Any = None
_daqp_update_ldp: Any = None
_daqp_deactivate_constraints: Any = None
_free_daqp_workspace: Any = None
_free_daqp_ldp: Any = None
try:
    import daqp as _daqp
    import llvmlite.binding as _llvm

    if types is None:
        raise ImportError("numba is not installed")

    _VERSION = importlib.metadata.version("daqp")
    if _VERSION not in BOUND_VERSIONS:
        unavailable_reason = (
            f"daqp {_VERSION} is installed; its C structs are bound for {BOUND_VERSIONS} only"
        )
    else:
        _llvm.load_library_permanently(_daqp.__file__)
        _library = ctypes.CDLL(_daqp.__file__)
        _daqp_quadprog = types.ExternalFunction(
            "daqp_quadprog", types.void(types.voidptr, types.voidptr, types.voidptr)
        )
        # daqp_quadprog's own steps (api.c), for a workspace kept between two QPs
        _setup_daqp_main = types.ExternalFunction(
            "setup_daqp_main",
            types.int32(types.voidptr, types.voidptr, types.voidptr, types.int32),
        )
        _daqp_solve = types.ExternalFunction("daqp_solve", types.void(types.voidptr, types.voidptr))
        _daqp_update_ldp = types.ExternalFunction(
            "daqp_update_ldp", types.int32(types.int32, types.voidptr, types.voidptr)
        )
        _daqp_deactivate_constraints = types.ExternalFunction(
            "daqp_deactivate_constraints", types.void(types.voidptr)
        )
        _free_daqp_workspace = types.ExternalFunction(
            "free_daqp_workspace", types.void(types.voidptr)
        )
        _free_daqp_ldp = types.ExternalFunction("free_daqp_ldp", types.void(types.voidptr))
        _LOADED = True
except Exception as error:  # pragma: no cover - depends on the installation
    unavailable_reason = f"DAQP's C library could not be bound: {type(error).__name__}: {error}"


@njit(cache=True)
def quadprog(
    H: Any,
    f: Any,
    A: Any,
    bupper: Any,
    blower: Any,
    sense: Any,
    x: Any,
    lam: Any,
    problem: Any,
    result: Any,
    settings: Any,
) -> tuple[int, int]:
    """``daqp_quadprog`` on C-contiguous arrays: ``(exit flag, iterations)``.

    ``bupper``/``blower``/``sense`` have ``ms + rows(A)`` entries, the first ``ms`` the
    simple bounds of ``x``; ``x`` (n) and ``lam`` (ms + rows) receive the solution;
    ``problem``/``result``/``settings`` are :class:`DaqpNative`'s struct buffers.
    """
    _write_problem(H, f, A, bupper, blower, sense, x, lam, problem, result)
    _daqp_quadprog(result.ctypes.data, problem.ctypes.data, settings.ctypes.data)
    r32 = result.view(np.int32)
    return int(r32[_R_FLAG]), int(r32[_R_ITER])


@njit(cache=True)
def _write_problem(
    H: Any, f: Any, A: Any, bupper: Any, blower: Any, sense: Any, x: Any, lam: Any,
    problem: Any, result: Any,
) -> None:  # fmt: skip
    """The ``DAQPProblem`` of :func:`quadprog`'s arguments into ``problem``, and the
    solution's arrays into ``result``."""
    p32 = problem.view(np.int32)
    p64 = problem.view(np.int64)
    m = bupper.shape[0]
    p32[_P_N] = H.shape[0]
    p32[_P_M] = m
    p32[_P_MS] = m - A.shape[0]
    p64[_P_H] = H.ctypes.data
    p64[_P_F] = f.ctypes.data
    p64[_P_A] = A.ctypes.data if A.shape[0] > 0 else 0
    p64[_P_BU] = bupper.ctypes.data
    p64[_P_BL] = blower.ctypes.data
    p64[_P_SENSE] = sense.ctypes.data
    p64[_P_BP] = 0
    p32[_P_NH] = 0
    p32[_P_TYPE] = 0
    r64 = result.view(np.int64)
    r64[_R_X] = x.ctypes.data
    r64[_R_LAM] = lam.ctypes.data


@njit(cache=True)
def quadprog_kept(
    H: Any, f: Any, A: Any, bupper: Any, blower: Any, sense: Any, x: Any, lam: Any,
    problem: Any, result: Any, settings: Any, work: Any, keep: bool,
) -> tuple[int, int, bool]:  # fmt: skip
    """:func:`quadprog` as ``daqp_quadprog``'s own steps (api.c: ``setup_daqp_main`` with
    the unconstrained check and equality elimination, ``daqp_solve``, the frees) on the
    caller's ``DAQPWorkspace`` ``work`` (:data:`WORKSPACE_BYTES`, 8-byte aligned): the same
    steps, so the same result to the last bit. Returns ``(exit flag, iterations, kept)``.

    Kept (``work`` still set up, for one :func:`box_quadprog_from`, which frees it) where
    ``keep``, DAQP proved the QP infeasible (exit flag -1) and no row has bounds closer
    than the settings' ``zero_tol`` (DAQP would eliminate it, or make it an immutable
    active row, which skips the unconstrained check that forms the bounds' LDP terms the
    box QP reuses): the Cholesky factor of H, its inverse and the linear term stay
    formed. ``keep`` is the caller's word that DAQP factored H unregularized (no proximal
    iterations: the settings' ``eps_prox`` is not positive and :func:`objective_bound` is
    finite for H).
    """
    _write_problem(H, f, A, bupper, blower, sense, x, lam, problem, result)
    words = work.view(np.int64)
    words[:] = 0
    words[_W_SETTINGS] = settings.ctypes.data  # the caller's settings (never freed)
    r32 = result.view(np.int32)
    flag = _setup_daqp_main(
        problem.ctypes.data, work.ctypes.data, result[_R_SETUP_BYTE:].ctypes.data,
        _UPDATE_UNCONSTRAINED | _UPDATE_ELIMINATE,
    )  # fmt: skip
    r32[_R_FLAG] = flag
    if flag < 0:  # (daqp_quadprog frees nothing then)
        return flag, int(r32[_R_ITER]), False
    _daqp_solve(result.ctypes.data, work.ctypes.data)
    flag, iterations = int(r32[_R_FLAG]), int(r32[_R_ITER])
    if keep and flag == -1:
        rows = A.shape[0]
        ms = bupper.shape[0] - rows
        zero_tol = settings.view(np.float64)[_S_ZERO]
        for i in range(ms, ms + rows):
            if bupper[i] - blower[i] < zero_tol:
                keep = False
        if keep:
            return flag, iterations, True
    release_workspace(work)
    return flag, iterations, False


@njit(cache=True)
def box_quadprog_from(
    work: Any,
    H: Any,
    f: Any,
    A: Any,
    bupper: Any,
    blower: Any,
    sense: Any,
    x: Any,
    lam: Any,
    problem: Any,
    result: Any,
    settings: Any,
) -> tuple[int, int]:
    """:func:`quadprog` on a QP with no rows (``A`` has none) whose bounds on ``x`` are
    the first of the kept QP's (``bupper``/``blower``: the same values; the kept LDP terms
    of the bounds are reused, not formed from these) and whose H and f are the QP's that
    :func:`quadprog_kept` kept in ``work``, cold (``sense`` zeros), on that workspace: its
    working set dropped (``daqp_deactivate_constraints``), the QP's size and the cold
    working set installed (``daqp_update_ldp`` of the working set alone: H's factor, its
    inverse, the linear term and the bounds' terms kept), ``daqp_solve``; ``work`` freed.
    The same result as :func:`quadprog`, bit for bit (the self-test at the first
    :func:`native`; ``tests/test_daqp_native.py``), without factoring H again. Where the
    new QP's unconstrained optimum holds (one iteration), a fresh :func:`quadprog` gives
    the result instead: DAQP's set-up computes that point by triangular solves, the kept
    workspace by H's formed inverse (other last bits); likewise for rows or a warm
    working set (not what this is for). Returns ``(exit flag, iterations)``."""  # fmt: skip
    warm = False
    for i in range(sense.shape[0]):
        if sense[i] != 0:
            warm = True
    if A.shape[0] > 0 or warm:  # (not the QP this is for: a fresh solve)
        release_workspace(work)
        return quadprog(H, f, A, bupper, blower, sense, x, lam, problem, result, settings)
    _write_problem(H, f, A, bupper, blower, sense, x, lam, problem, result)
    _daqp_deactivate_constraints(work.ctypes.data)
    updated = _daqp_update_ldp(_UPDATE_SENSE, work.ctypes.data, problem.ctypes.data)
    flag, iterations = 0, 0
    if updated >= 0:
        result.view(np.float64)[_R_SETUP] = 0.0  # (no set-up: DAQP's clock for the solve)
        _daqp_solve(result.ctypes.data, work.ctypes.data)
        r32 = result.view(np.int32)
        flag, iterations = int(r32[_R_FLAG]), int(r32[_R_ITER])
    release_workspace(work)
    if updated < 0 or iterations == 1:  # (a failed update: DAQP's own words, fresh)
        return quadprog(H, f, A, bupper, blower, sense, x, lam, problem, result, settings)
    return flag, iterations


@njit(cache=True)
def release_workspace(work: Any) -> None:
    """Free what DAQP allocated in the kept workspace ``work`` (api.c's frees), the
    caller's settings left alone."""
    work.view(np.int64)[_W_SETTINGS] = 0
    _free_daqp_workspace(work.ctypes.data)
    _free_daqp_ldp(work.ctypes.data)


@njit(cache=True)
def objective_bound(
    H: Any,
    f: Any,
    lower: Any,
    upper: Any,
    hessian_floor: float,
    tolerance: float,
    zero_tol: float,
) -> float:
    """The compiled twin of :func:`ltv_lstm_mpc.solvers.daqp_.objective_bound` (the same
    terms, summed in order): DAQP's ``fval_bound`` for a QP with bounds ``lower`` /
    ``upper`` on its variables, or :data:`NO_BOUND`."""
    n = f.shape[0]
    if not hessian_floor > 0.0:
        return NO_BOUND
    trace, radius, linear, gradient = 0.0, 0.0, 0.0, 0.0
    for i in range(n):
        low, high = abs(lower[i]), abs(upper[i])
        if not (low < np.inf and high < np.inf):  # an infinite bound (or NaN): no bound
            return NO_BOUND
        r = max(low, high) + tolerance
        trace += H[i, i]
        radius += r * r
        linear += abs(f[i]) * r
        gradient += f[i] * f[i]
    if not (
        trace >= 0.0
        and hessian_floor > zero_tol
        and hessian_floor > zero_tol * trace
        and n * _EPSILON * trace <= ROUNDING_MARGIN * hessian_floor
        and trace <= CONDITION_LIMIT * hessian_floor
    ):  # (DAQP could regularize H: its proximal mode, whose objective this does not bound)
        return NO_BOUND
    bound = 2.0 * (0.5 * trace * radius + linear + 0.5 * gradient / hessian_floor)
    if not bound < NO_BOUND:
        return NO_BOUND
    return bound


@njit(cache=True)
def set_objective_bound(
    settings: Any, H: Any, f: Any, lower: Any, upper: Any, hessian_floor: float, own: float
) -> float:
    """Write the smaller of ``own`` (the settings' own ``fval_bound``: :data:`NO_BOUND`
    unless they name one) and :func:`objective_bound` (with the settings' ``primal_tol``
    and ``zero_tol``) into the ``fval_bound`` of DAQP's settings buffer ``settings`` for
    the next :func:`quadprog`; ``own`` where the settings ask for proximal iterations
    (``eps_prox`` > 0). Every call writes: no bound of another QP stays behind.

    Returns :func:`objective_bound` (:data:`NO_BOUND` where the settings ask for proximal
    iterations): finite only where DAQP factors H as it is (no regularization)."""
    s = settings.view(np.float64)
    if s[_S_PROX] > 0.0:
        s[_S_FVAL] = own
        return NO_BOUND
    bound = objective_bound(H, f, lower, upper, hessian_floor, s[_S_PRIMAL], s[_S_ZERO])
    s[_S_FVAL] = min(own, bound)
    return bound


@njit(cache=True)
def activity_infeasible(A: Any, lower: Any, upper: Any, tolerance: float) -> bool:
    """The compiled twin of :func:`ltv_lstm_mpc.solvers.daqp_.activity_infeasible` (the same
    sums in the same order, the same rows passed over): whether one row of the QP cannot
    hold, to within ``tolerance``, anywhere in its variables' box (``lower`` / ``upper`` in
    DAQP's layout, the bounds first): then the QP is infeasible."""
    rows, n = A.shape
    if rows == 0:
        return False
    origin = tolerance >= 0.0  # the origin in the widened box: rows it satisfies prove
    for j in range(n):  # nothing
        if not (lower[j] - tolerance <= 0.0 <= upper[j] + tolerance):
            origin = False
    for i in range(rows):
        if origin and lower[n + i] <= 0.0 <= upper[n + i]:
            continue
        smallest, largest, size = 0.0, 0.0, 0.0
        provable = True
        row = A[i]
        for j in range(n):
            a = row[j]
            if a == 0.0:
                continue
            if not (abs(lower[j]) < NO_BOUND and abs(upper[j]) < NO_BOUND):
                provable = False
                break
            low, high = a * (lower[j] - tolerance), a * (upper[j] + tolerance)
            smallest += min(low, high)
            largest += max(low, high)
            size += max(abs(low), abs(high))
        if not provable:
            continue
        lo, up = lower[n + i], upper[n + i]
        if up < NO_BOUND and smallest - up > tolerance + ACTIVITY_MARGIN * (size + abs(up)):
            return True
        if lo > -NO_BOUND and lo - largest > tolerance + ACTIVITY_MARGIN * (size + abs(lo)):
            return True
    return False


@njit(cache=True)
def primal_tolerance(settings: Any) -> float:
    """The ``primal_tol`` of DAQP's settings buffer ``settings``."""
    return float(settings.view(np.float64)[_S_PRIMAL])


def write_fval_bound(settings: NDArray[np.uint8], value: float) -> None:
    """Write ``fval_bound`` into DAQP's settings buffer ``settings`` (from Python)."""
    settings.view(np.float64)[_S_FVAL] = value


@njit(cache=True)
def solver_seconds(result: Any) -> float:
    """Setup + solve time of the last :func:`quadprog` call, by DAQP's own clock (s)."""
    r = result.view(np.float64)
    return float(r[_R_SETUP] + r[_R_SOLVE])


class DaqpNative:
    """Struct buffers for :func:`quadprog` with fixed settings (one per solver session).

    Parameters
    ----------
    options : mapping
        ``daqp.solve`` keyword settings (DAQP's defaults for the others).
    """

    def __init__(self, options: Mapping[str, Any]) -> None:
        settings = _Settings()
        _library.daqp_default_settings(ctypes.byref(settings))
        names = {field[0] for field in _Settings._fields_}
        for key, value in options.items():
            if key not in names:
                raise KeyError(f"{key!r} is not a DAQPSettings field ({sorted(names)})")
            setattr(settings, key, value)
        #: The three C structs as byte buffers (8-byte aligned).
        self.settings = _buffer(ctypes.string_at(ctypes.byref(settings), ctypes.sizeof(settings)))
        self.problem = _buffer(bytes(ctypes.sizeof(_Problem)))
        self.result = _buffer(bytes(ctypes.sizeof(_Result)))
        #: A caller-owned ``DAQPWorkspace`` for :func:`quadprog_kept` and
        #: :func:`box_quadprog_from` (no bytes where their self-test failed: then nothing
        #: is kept).
        self.work = _buffer(bytes(WORKSPACE_BYTES if _KEEPS else 0))

    def solve(
        self,
        H: FloatArray,
        f: FloatArray,
        A: FloatArray,
        bupper: FloatArray,
        blower: FloatArray,
        sense: NDArray[np.intc],
    ) -> tuple[FloatArray, FloatArray, int, int]:
        """One cold solve from Python: ``(x, lam, exit flag, iterations)`` (fresh arrays)."""
        x = np.empty(H.shape[0])
        lam = np.empty(bupper.shape[0])
        flag, iterations = quadprog(
            H, f, A, bupper, blower, sense, x, lam, self.problem, self.result, self.settings
        )
        return x, lam, flag, iterations


def _buffer(data: bytes) -> NDArray[np.uint8]:
    """A writable, 8-byte aligned uint8 copy of ``data``."""
    words = np.zeros((len(data) + 7) // 8, dtype=np.int64)
    raw = words.view(np.uint8)[: len(data)]
    raw[:] = np.frombuffer(data, dtype=np.uint8)
    return raw


#: The compiled functions the binding's self-tests at the first :func:`native` compile
#: (or load from numba's cache): on the kernel lists of the compiled forms that bind it.
SELF_TEST_KERNELS = (quadprog, quadprog_kept, box_quadprog_from, objective_bound,
                     activity_infeasible)  # fmt: skip

_CHECKED: bool | None = None
#: :func:`box_quadprog_from` gave :func:`quadprog`'s result bit for bit in the self-test.
_KEEPS = False


def _self_test() -> bool:
    """The binding and ``daqp.solve`` agree exactly on a small QP (layout check); compiles
    :func:`objective_bound` and :func:`activity_infeasible` too."""
    rng = np.random.default_rng(7)
    n, rows = 4, 6
    M = rng.standard_normal((n, n))
    H = M @ M.T + np.eye(n)
    f = rng.standard_normal(n)
    A = rng.standard_normal((rows, n))
    bupper = np.concatenate([np.full(n, 0.3), rng.random(rows) * 0.2])
    blower = -bupper
    sense = np.zeros(n + rows, dtype=np.intc)
    x, lam, flag, iterations = DaqpNative({"primal_tol": 1e-9}).solve(
        H, f, A, bupper, blower, sense
    )
    x_ref, _, flag_ref, info = _daqp.solve(H, f, A, bupper, blower, sense, primal_tol=1e-9)
    # the dense backend's compiled bound beside quadprog: compiled (and cached) with it, so
    # that a controller whose steps never call it from Python still finds it ready
    objective_bound(H, f, blower[:n], bupper[:n], 1.0, 1e-9, 1e-11)
    activity_infeasible(A, blower, bupper, 1e-9)  # (likewise)
    return bool(
        flag == flag_ref
        and iterations == info["iterations"]
        and np.array_equal(x, x_ref)
        and np.array_equal(lam, info["lam"])
    )


def _keep_self_test() -> bool:
    """A kept workspace (:func:`quadprog_kept`) and :func:`box_quadprog_from` give a fresh
    :func:`quadprog`'s result bit for bit on two QPs (a row no point of the box satisfies,
    so the QP with it is infeasible; the box QP's unconstrained optimum outside the box,
    then inside it); the workspace's layout and DAQP's update steps are as bound."""
    rng = np.random.default_rng(11)
    n, rows = 6, 4
    M = rng.standard_normal((n, n))
    H = M @ M.T + 0.5 * np.eye(n)
    A = rng.standard_normal((rows, n))
    bupper = np.concatenate([np.full(n, 1.0), np.full(rows, 2.0)])
    blower = -bupper
    blower[n + 1] = 1.5 * np.abs(A[1]).sum()  # beyond the row's reach in the box
    bupper[n + 1] = 2.0 * blower[n + 1]
    sense = np.zeros(n + rows, dtype=np.intc)
    buffers = DaqpNative({"primal_tol": 1e-9})
    work = _buffer(bytes(WORKSPACE_BYTES))
    for scale in (30.0, 0.01):  # the box QP's optimum on the box's faces, then inside it
        f = scale * rng.standard_normal(n)
        x, lam = np.empty(n), np.empty(n + rows)
        kept_flag, _, kept = quadprog_kept(
            H, f, A, bupper, blower, sense, x, lam, buffers.problem, buffers.result,
            buffers.settings, work, True,
        )  # fmt: skip
        if not (kept and kept_flag == -1):
            return False
        box = (bupper[:n].copy(), blower[:n].copy(), sense[:n].copy())
        x_from, lam_from = np.empty(n), np.empty(n)
        flag, iterations = box_quadprog_from(
            work, H, f, A[:0], *box, x_from, lam_from, buffers.problem, buffers.result,
            buffers.settings,
        )  # fmt: skip
        x_ref, lam_ref = np.empty(n), np.empty(n)
        flag_ref, iterations_ref = quadprog(
            H, f, A[:0], *box, x_ref, lam_ref, buffers.problem, buffers.result,
            buffers.settings,
        )  # fmt: skip
        if not (
            flag == flag_ref
            and iterations == iterations_ref
            and np.array_equal(x_from, x_ref)
            and np.array_equal(lam_from, lam_ref)
        ):
            return False
    return True


def bound() -> bool:
    """DAQP's C library is bound (a release in :data:`BOUND_VERSIONS`); the self-test still
    runs at the first :func:`native`."""
    return _LOADED


def ready() -> bool:
    """:func:`native` would return without compiling: the library is bound, and its
    self-tests ran in this process or the kernels they compile (:data:`SELF_TEST_KERNELS`,
    :func:`objective_bound` among them, which the dense backend calls beside
    :func:`quadprog`) are in numba's on-disk cache."""
    from ltv_lstm_mpc.numba_support import ready as compiled_ready

    return _LOADED and (_CHECKED is not None or compiled_ready(list(SELF_TEST_KERNELS)))


def native(options: Mapping[str, Any]) -> DaqpNative | None:
    """A :class:`DaqpNative` for ``options``, or ``None`` (then see :data:`unavailable_reason`).

    The first call runs the layout self-test; a failure disables the binding for the process.
    """
    global _CHECKED, _KEEPS, unavailable_reason
    if not _LOADED:
        return None
    if _CHECKED is None:
        try:
            _CHECKED = _self_test()
        except Exception as error:  # pragma: no cover - a broken binding
            _CHECKED = False
            unavailable_reason = f"DAQP binding self-test raised {type(error).__name__}: {error}"
        else:
            if not _CHECKED:  # pragma: no cover
                unavailable_reason = "DAQP binding self-test: results differ from daqp.solve"
        if _CHECKED:  # a kept workspace only where it gives the same bits (else: fresh)
            try:
                _KEEPS = _keep_self_test()
            except Exception:  # pragma: no cover - a broken binding of the update steps
                _KEEPS = False
    if not _CHECKED:
        return None
    try:
        return DaqpNative(options)
    except KeyError as error:
        unavailable_reason = str(error)
        return None
