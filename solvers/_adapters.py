"""Generic adapters between the two problem forms (internal).

- :func:`dense_from_convex`: a :class:`~.dense.DenseBackend` on top of a
  ConvexProblem :class:`~._base.Backend` (each :class:`~.dense.DenseQP` is
  converted with :meth:`~.dense.DenseQP.to_convex_problem`): every registered
  solver accepts dense QPs, slowly where it has no dense backend of its own.
- :func:`convex_from_dense`: a ConvexProblem :class:`~._base.Backend` on top of a
  dense backend (``quadprog``, ``proxqp``, users' dense-only backends):
  equalities become rows with ``lo = up``, missing bounds are infinite; the cones
  become :class:`~.dense.DenseCone` for a dense backend that solves them
  (``clarabel``) and are refused by the session on every QP-only one.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import Any, ClassVar, cast

import numpy as np

from ._base import Backend, BackendFactory, FloatArray, RawResult, WarmStart
from .dense import DenseBackend, DenseBackendFactory, DenseQP
from .problem import ConvexProblem, Solution

__all__ = ["convex_from_dense", "dense_from_convex", "dense_qp_of"]


# --------------------------------------------------------------------------------------
# dense QPs on a ConvexProblem backend
# --------------------------------------------------------------------------------------
class DenseFromConvex(DenseBackend):
    """Solves each :class:`DenseQP` as its :meth:`~DenseQP.to_convex_problem`."""

    backend: ClassVar[str] = "adapter"
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True

    def __init__(
        self,
        factory: BackendFactory,
        inner: Backend,
        tolerance: float,
        settings: Mapping[str, Any],
    ) -> None:
        """``inner`` is a fresh backend made by ``factory``."""
        super().__init__(inner.name, inner.solver, inner.options)
        self._factory = factory
        self._tolerance = tolerance
        self._settings = dict(settings)
        self._inner = inner
        self._used = False
        self._key = ""
        self._notes: tuple[str, ...] = ()

    def _make(self) -> Backend:
        return self._factory(self.name, self._tolerance, self._settings)

    def handles_cones(self) -> bool:
        """Cones are passed on to the inner backend: exact where it solves them."""
        return self._inner.handles_cones()

    def setup(self, qp: DenseQP) -> None:
        """Convert and set the inner backend up."""
        problem = qp.to_convex_problem()
        if self._used:
            self._inner = self._make()
        self._used = True
        self._inner.setup(problem)
        self._key = problem.structure_key()
        self._notes = ()

    def update(self, qp: DenseQP) -> None:
        """Convert; update the inner backend in place when it can, else set it up afresh."""
        problem = qp.to_convex_problem()
        if self._inner.supports_update and problem.structure_key() == self._key:
            self._inner.update(problem)
            self._notes = ()
            return
        why = (
            "backend cannot update in place"
            if not self._inner.supports_update
            else "finite-bound pattern changed"
        )
        self._inner = self._make()
        self._inner.setup(problem)
        self._key = problem.structure_key()
        self._notes = (f"fresh setup ({why})",)

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve with the inner backend (multipliers without the empty ``"eq"``)."""
        if isinstance(warm_start, Solution) and warm_start.duals is not None:
            duals = dict(warm_start.duals)
            duals.setdefault("eq", np.zeros(0))
            warm_start = dataclasses.replace(warm_start, duals=duals)
        raw = self._inner.solve(warm_start)

        def without_eq(rows: Mapping[str, FloatArray] | None) -> Mapping[str, FloatArray] | None:
            return None if rows is None else {k: v for k, v in rows.items() if k != "eq"}

        return dataclasses.replace(
            raw,
            duals=without_eq(raw.duals),
            certificate=without_eq(raw.certificate),
            notes=(*self._notes, *raw.notes),
        )


@functools.cache
def _dense_class(inner: type[Backend]) -> type[DenseFromConvex]:
    attrs = {"backend": inner.backend, "supports_warm_start": inner.supports_warm_start}
    return cast(type[DenseFromConvex], type(f"Dense{inner.__name__}", (DenseFromConvex,), attrs))


def dense_from_convex(factory: BackendFactory) -> DenseBackendFactory:
    """Dense factory serving :class:`DenseQP` through the ConvexProblem ``factory``."""

    def make(name: str, tolerance: float, settings: Mapping[str, Any]) -> DenseBackend:
        inner = factory(name, tolerance, settings)
        return _dense_class(type(inner))(factory, inner, tolerance, settings)

    return make


# --------------------------------------------------------------------------------------
# ConvexProblems on a dense backend
# --------------------------------------------------------------------------------------
def dense_qp_of(problem: ConvexProblem) -> DenseQP:
    """``problem`` as a :class:`DenseQP` (:meth:`DenseQP.from_convex_problem`)."""
    return DenseQP.from_convex_problem(problem)


class ConvexFromDense(Backend):
    """Solves a :class:`ConvexProblem` with a dense backend (cones only where it solves them)."""

    backend: ClassVar[str] = "adapter"
    supports_cones: ClassVar[bool] = False
    supports_update: ClassVar[bool] = True
    supports_warm_start: ClassVar[bool] = True

    def __init__(
        self,
        factory: DenseBackendFactory,
        inner: DenseBackend,
        tolerance: float,
        settings: Mapping[str, Any],
    ) -> None:
        """``inner`` is a fresh dense backend made by ``factory``."""
        super().__init__(inner.name, inner.solver, inner.options)
        self._factory = factory
        self._tolerance = tolerance
        self._settings = dict(settings)
        self._inner = inner
        self._used = False
        self._p = 0
        self._notes: tuple[str, ...] = ()

    def handles_cones(self) -> bool:
        """Whether the dense backend solves second-order cones."""
        return self._inner.handles_cones()

    def refines_cone_points(self) -> bool:
        """Whether the dense backend's cone points are the local SQP's solution."""
        return self._inner.refines_cone_points()

    def setup(self, problem: ConvexProblem) -> None:
        """Convert and set the dense backend up."""
        qp = dense_qp_of(problem)
        qp.check()
        if self._used:
            self._inner = self._factory(self.name, self._tolerance, self._settings)
        self._used = True
        self._inner.setup(qp)
        self._p = problem.n_eq
        self._notes = ()

    def update(self, problem: ConvexProblem) -> None:
        """Convert; update the dense backend in place when it can, else set it up afresh."""
        qp = dense_qp_of(problem)
        if self._inner.supports_update:
            self._inner.update(qp)
            self._notes = ()
        else:
            self._inner = self._factory(self.name, self._tolerance, self._settings)
            self._inner.setup(qp)
            self._notes = ("fresh setup (backend cannot update in place)",)

    def solve(self, warm_start: WarmStart | None) -> RawResult:
        """Solve with the dense backend; split the row multipliers into ``eq`` and ``ineq``."""
        p = self._p
        if isinstance(warm_start, Solution) and warm_start.duals is not None:
            d = warm_start.duals
            if "eq" in d and "ineq" in d:
                duals_in = {k: v for k, v in d.items() if k != "eq"}
                duals_in["ineq"] = np.concatenate([d["eq"], d["ineq"]])
                warm_start = dataclasses.replace(warm_start, duals=duals_in)
        raw = self._inner.solve(warm_start)

        def split(rows: Mapping[str, FloatArray] | None) -> Mapping[str, FloatArray] | None:
            if rows is None or "ineq" not in rows:
                return rows
            y = np.asarray(rows["ineq"])
            return {**rows, "eq": y[:p].copy(), "ineq": y[p:].copy()}

        return dataclasses.replace(
            raw,
            duals=split(raw.duals),
            certificate=split(raw.certificate),
            notes=(*self._notes, *raw.notes),
        )


@functools.cache
def _convex_class(inner: type[DenseBackend]) -> type[ConvexFromDense]:
    attrs = {"backend": inner.backend, "supports_warm_start": inner.supports_warm_start}
    return cast(type[ConvexFromDense], type(f"Convex{inner.__name__}", (ConvexFromDense,), attrs))


def convex_from_dense(factory: DenseBackendFactory) -> BackendFactory:
    """ConvexProblem factory serving cone-free problems through the dense ``factory``."""

    def make(name: str, tolerance: float, settings: Mapping[str, Any]) -> Backend:
        inner = factory(name, tolerance, settings)
        return _convex_class(type(inner))(factory, inner, tolerance, settings)

    return make
