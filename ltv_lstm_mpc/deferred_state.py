"""State that a compiled step leaves in its record rows, written into its owners on first use.

The controller's one-call step (:mod:`ltv_lstm_mpc.loop.compiled_step`) writes everything it
computes into preallocated record rows. The estimates, the reference calculator's last
solution and the MPC's plan that the next step starts from are in those rows too, so
between one-call steps nothing has to be copied or bound in Python: the owners
(:class:`~ltv_lstm_mpc.loop.observer.Observer`,
:class:`~ltv_lstm_mpc.loop.reference.ReferenceCalculator`,
:class:`~ltv_lstm_mpc.mpc.rti.RobustMPC`, the controller) declare those attributes
:class:`Deferred`, and while a row holds them their ``_pending`` is the controller's
function that writes them (:func:`defer`). The first read or assignment of any of them,
on any owner, calls it: every deferred value is written, as a view of its row, and
``_pending`` is cleared on all owners (:func:`settle`); then the read or assignment
proceeds as for a plain attribute.

So reading ``controller.observer.x_hat`` after a one-call step gives the estimate that step
left, as before, and a value assigned between steps is the one the next step uses. The
settings the one-call workspace holds (the reference calculator's tolerance, iterations
and jump bound, the MPC's reuse tolerance) are :class:`DeferredSetting`: assigning one
ends the deferral too, so the controller checks them only then. The other attributes of
the owners are plain (no cost), and a deferred attribute costs one check per access.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Generic, TypeVar, overload

__all__ = ["Deferred", "DeferredSetting", "DeferredState", "defer", "settle"]

T = TypeVar("T")


class DeferredState:
    """Mixin of the objects whose state a one-call step may keep in its record rows.

    ``_pending``: None, or the function that writes the :class:`Deferred` attributes
    (set by :func:`defer`, cleared by :func:`settle`).
    """

    _pending: Callable[[], None] | None = None

    def __getstate__(self) -> dict[str, Any]:
        """The instance's attributes, deferred values written first (copy and pickle)."""
        if self._pending is not None:
            self._pending()
        return dict(self.__dict__)


class Deferred(Generic[T]):
    """An instance attribute of a :class:`DeferredState` whose value may wait in a record
    row: reading or assigning it first calls the owner's ``_pending``. The value is kept
    in the instance's ``__dict__`` under the attribute's own name."""

    __slots__ = ("name",)

    def __init__(self) -> None:
        self.name = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, instance: None, owner: type | None = None) -> Deferred[T]: ...

    @overload
    def __get__(self, instance: DeferredState, owner: type | None = None) -> T: ...

    def __get__(self, instance: DeferredState | None, owner: type | None = None) -> Any:
        if instance is None:
            return self
        if instance._pending is not None:
            instance._pending()
        try:
            return instance.__dict__[self.name]
        except KeyError:
            raise AttributeError(
                f"{type(instance).__name__!r} object has no attribute {self.name!r}",
                name=self.name,
            ) from None

    def __set__(self, instance: DeferredState, value: T) -> None:
        if instance._pending is not None:
            instance._pending()
        instance.__dict__[self.name] = value


class DeferredSetting(Deferred[T]):
    """A setting that a deferred state was computed with (a tolerance the one-call
    workspace holds): assigning it first calls the owner's ``_pending``, so that the
    controller sees the change at its next step; reading it is a plain read."""

    __slots__ = ()

    @overload
    def __get__(self, instance: None, owner: type | None = None) -> DeferredSetting[T]: ...

    @overload
    def __get__(self, instance: DeferredState, owner: type | None = None) -> T: ...

    def __get__(self, instance: DeferredState | None, owner: type | None = None) -> Any:
        if instance is None:
            return self
        try:
            return instance.__dict__[self.name]
        except KeyError:
            raise AttributeError(
                f"{type(instance).__name__!r} object has no attribute {self.name!r}",
                name=self.name,
            ) from None


def defer(owner: DeferredState, pending: Callable[[], None]) -> None:
    """The :class:`Deferred` attributes of ``owner`` wait until ``pending`` writes them."""
    owner.__dict__["_pending"] = pending


def settle(owner: DeferredState, values: dict[str, Any]) -> None:
    """Write the deferred ``{name: value}`` into ``owner`` and clear its ``_pending``."""
    owner.__dict__.pop("_pending", None)
    owner.__dict__.update(values)
