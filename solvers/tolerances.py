"""One ``tolerance`` mapped to each solver's own option names (the table), and known settings.

The same numerical solver takes the same option names whichever interface
drives it (native, cvxpy or qpsolvers), so both tables are keyed by the
lower-case solver name.

=========  ==================================================================
solver     options set to ``tolerance``
=========  ==================================================================
clarabel   ``tol_gap_abs``, ``tol_gap_rel``, ``tol_feas``
daqp       ``primal_tol``, ``dual_tol``
ecos       ``abstol``, ``reltol``, ``feastol``
highs      ``primal_feasibility_tolerance``, ``dual_feasibility_tolerance``
osqp       ``eps_abs``, ``eps_rel``
piqp       ``eps_abs``, ``eps_rel``, ``eps_duality_gap_abs``, ``eps_duality_gap_rel``
proxqp     ``eps_abs``; ``eps_rel = 0`` (ProxQP's relative criterion scales with the
           data norms and left a 1e-5 relative objective error at ``eps_rel = 1e-8``)
quadprog   none (a dual active-set method that solves to machine precision)
scs        ``eps_abs``, ``eps_rel``
=========  ==================================================================

User settings passed next to ``tolerance`` override these entries.

Feasibility and optimality tolerances
-------------------------------------
:func:`feasibility_tolerance` is the absolute tolerance to which a caller
should check the constraint satisfaction of a returned point (with a relative
part: accept ``violation <= tol * (1 + |bound|)``). Solvers only meet their
``tolerance`` in their own scaled/relative measures, so the check is looser:

==========================================  ==================================
solver                                      feasibility tolerance
==========================================  ==================================
interior point / active set (clarabel,      ``max(1e-7, 100 * tolerance)``
ecos, piqp, daqp, quadprog, highs, ...)
first order (osqp, scs, proxqp, also as     ``max(1e-5, 1000 * tolerance)``
``cvxpy:OSQP``, ``qpsolvers:scs``, ...)
==========================================  ==================================

A registered solver is classified by its
``first_order`` of :class:`~ltv_lstm_mpc.solvers.SolverInfo`, any other name by its
last ``:``-separated part.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

from ltv_lstm_mpc.exceptions import InvalidValueError
from ltv_lstm_mpc.validation import real_scalar

__all__ = [
    "TOLERANCE_OPTIONS",
    "feasibility_tolerance",
    "known_settings",
    "optimality_tolerance",
    "solver_options",
]

#: Option names set to the single ``tolerance`` value, per solver (lower case).
TOLERANCE_OPTIONS: Mapping[str, tuple[str, ...]] = {
    "clarabel": ("tol_gap_abs", "tol_gap_rel", "tol_feas"),
    "daqp": ("primal_tol", "dual_tol"),
    "ecos": ("abstol", "reltol", "feastol"),
    "highs": ("primal_feasibility_tolerance", "dual_feasibility_tolerance"),
    "osqp": ("eps_abs", "eps_rel"),
    "piqp": ("eps_abs", "eps_rel", "eps_duality_gap_abs", "eps_duality_gap_rel"),
    "proxqp": ("eps_abs",),
    "quadprog": (),
    "scs": ("eps_abs", "eps_rel"),
}

#: Native solver names (lower case, last part of a registry name) of first-order methods.
FIRST_ORDER = frozenset({"osqp", "scs", "proxqp"})
#: Registry names added with ``register_backend`` (and ``testing.faulty``) -> first order;
#: kept by the registry, so that this module does not import it.
_REGISTERED_FIRST_ORDER: dict[str, bool] = {}


def note_registered(name: str, first_order: bool | None) -> None:
    """Record (``None``: forget) whether the registered solver ``name`` is first order."""
    if first_order is None:
        _REGISTERED_FIRST_ORDER.pop(name, None)
    else:
        _REGISTERED_FIRST_ORDER[name] = bool(first_order)


#: Options fixed next to the tolerance (documented in the table above).
_FIXED_OPTIONS: Mapping[str, Mapping[str, Any]] = {"proxqp": {"eps_rel": 0.0}}

_ECOS_SETTINGS = (
    "abstol",
    "reltol",
    "feastol",
    "abstol_inacc",
    "reltol_inacc",
    "feastol_inacc",
    "max_iters",
    "nitref",
)


@functools.cache
def known_settings(solver: str) -> tuple[str, ...] | None:
    """Names of the native settings of ``solver``, or ``None`` when they cannot be listed.

    Introspected from the installed package where it exposes them (osqp,
    piqp, daqp, clarabel); ``None`` means the settings are passed through and
    the solver's own interface decides what to do with unknown names.
    """
    key = solver.lower()
    try:
        if key == "osqp":
            import osqp

            names = [k for k in dir(osqp.OSQP().ext.OSQPSettings) if not k.startswith("_")]
            return (*names, "solver_type", "cg_preconditioner")
        if key == "piqp":
            import piqp

            return tuple(k for k in dir(piqp.SparseSolver().settings) if not k.startswith("_"))
        if key == "daqp":
            import daqp

            return tuple(daqp.Model().settings)
        if key == "proxqp":
            import proxsuite

            settings = proxsuite.proxqp.dense.QP(1, 0, 0, False).settings
            return tuple(k for k in dir(settings) if not k.startswith("_"))
        if key == "clarabel":
            import clarabel

            return tuple(k for k in dir(clarabel.DefaultSettings()) if not k.startswith("_"))
    except ImportError:  # pragma: no cover - only called for installed solvers
        return None
    if key == "ecos":
        return _ECOS_SETTINGS
    if key == "quadprog":
        return ()
    return None


def solver_options(solver: str, tolerance: float, settings: Mapping[str, Any]) -> dict[str, Any]:
    """Merge the tolerance options of ``solver`` with the user's ``settings`` (settings win).

    Raises
    ------
    InvalidValueError
        If ``tolerance`` is not a positive finite number.
    """
    tol = real_scalar("tolerance", tolerance)
    if not (tol > 0.0 and tol < float("inf")):
        raise InvalidValueError(f"tolerance must be a positive finite float, got {tolerance!r}")
    names = TOLERANCE_OPTIONS.get(solver.lower(), ())
    options: dict[str, Any] = dict.fromkeys(names, tol)
    options.update(_FIXED_OPTIONS.get(solver.lower(), {}))
    options.update(settings)
    return options


def feasibility_tolerance(solver: str, tolerance: float) -> float:
    """Absolute tolerance for checking a point returned by ``solver`` run at ``tolerance``.

    ``max(1e-7, 100 * tolerance)`` for interior-point and active-set solvers,
    ``max(1e-5, 1e3 * tolerance)`` for first-order ones (osqp, scs, proxqp,
    through any interface); see the module docstring. Callers accept a
    violation up to ``feasibility_tolerance(...) * (1 + |bound|)``.

    Raises
    ------
    InvalidValueError
        If ``tolerance`` is not a positive finite number.
    """
    tol = real_scalar("tolerance", tolerance)
    if not (tol > 0.0 and tol < float("inf")):
        raise InvalidValueError(f"tolerance must be a positive finite float, got {tolerance!r}")
    first_order = _REGISTERED_FIRST_ORDER.get(solver) if isinstance(solver, str) else None
    if first_order is None:
        first_order = str(solver).rsplit(":", 1)[-1].lower() in FIRST_ORDER
    if first_order:
        return max(1e-5, 1e3 * tol)
    return max(1e-7, 100.0 * tol)


def optimality_tolerance(solver: str, tolerance: float) -> float:
    """Relative tolerance of the stationarity and complementarity residuals of a point.

    The acceptance check (:mod:`~ltv_lstm_mpc.solvers.acceptance`) holds the KKT
    residuals of a returned point to this: :func:`feasibility_tolerance`, except for
    ECOS (through any interface): ``max(1e-4, 1e4 * tolerance)``. ECOS gets a QP's
    quadratic objective as a second-order cone (an epigraph variable), and the
    multipliers of the original rows it returns satisfy stationarity only to about
    ``6e-5`` relative at ``tolerance = 1e-8`` (measured on the layer's random QPs and MPC
    problems) while its points agree with the interior-point solvers' to ``1e-6``.

    Raises
    ------
    InvalidValueError
        If ``tolerance`` is not a positive finite number.
    """
    value = feasibility_tolerance(solver, tolerance)
    if str(solver).rsplit(":", 1)[-1].lower() == "ecos":
        return max(value, 1e-4, 1e4 * float(tolerance))
    return value
