r"""The one implementation of eq. (lstm) and of its Jacobians eq. (jacobian).

Every part of the library that evaluates the LSTM goes through :class:`LSTMKernel`: the
model (:meth:`~ltv_lstm_mpc.LSTMModel.step`, ``simulate``,
``step_and_jacobians``), the observer eq. (lstm_observer) (through the gate injection
``extra``), the reference calculator eq. (reference_calculation) and both MPC
transcriptions (rollout along the candidate, batched linearization, re-simulation of the
plan). So they agree bit for bit.

With the stacked gate weights :math:`[U\; W\; b]` (gate order f, i, o, c) and
:math:`x = [c; h]`,

.. math::

    z = [U\; W\; b] [h; u; 1] + e, \quad
    f, i, o = \sigma(z_{f,i,o}), \; g = \tanh(z_c), \quad
    c^+ = f \odot c + i \odot g, \quad h^+ = o \odot \tanh(c^+),

where :math:`e` is zero for the model and :math:`[L_f; L_i; L_o; 0](y - \hat y)` for the
observer. The Jacobians reuse the stored activations: with
:math:`D = [c\,\sigma_f', g\,\sigma_i', \tanh(c^+)\sigma_o', i (1-g^2)]`,
:math:`\partial c^+/\partial[h; u] = \sum_{g \in f,i,c} D_g [U_g\; W_g]`,
:math:`\partial c^+/\partial c = \mathrm{diag}(f)` and
:math:`\partial h^+ = o(1-\tanh^2 c^+)\,\partial c^+ + D_o [0\; U_o\; W_o]`.

All work happens in preallocated :class:`Trajectory` buffers (no allocation per step):
the real-time building block. The numpy code below is the readable reference; by default
the kernel runs the same loops compiled with numba (:mod:`ltv_lstm_mpc.lstm.compiled`,
tested against this reference to 1e-12). ``LSTMKernel(model, compiled=False)`` or the
environment variable ``LTV_LSTM_MPC_KERNEL=numpy`` select the reference.
"""

from __future__ import annotations

import os
import warnings
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.special import expit

from ltv_lstm_mpc.lstm import compiled as _compiled

if TYPE_CHECKING:  # pragma: no cover
    from ltv_lstm_mpc.lstm.model import LSTMModel

__all__ = ["LSTMKernel", "Trajectory"]

FloatArray = NDArray[np.float64]


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

    @property
    def A(self) -> FloatArray:
        """State Jacobians :math:`A_k`, view ``(N, 2n, 2n)``."""
        return self.J[:, :, : 2 * self.n]

    @property
    def B(self) -> FloatArray:
        """Input Jacobians :math:`B_k`, view ``(N, 2n, m)``."""
        return self.J[:, :, 2 * self.n :]


def _cell(
    WU: FloatArray,
    view: tuple[FloatArray, ...],
    cn: FloatArray,
    hn: FloatArray,
    tmp: FloatArray,
    extra: FloatArray | None,
) -> None:
    r"""One step of eq. (lstm) in place, on the views of one step of a :class:`Trajectory`
    (the numpy reference; ``lstm/compiled.py`` has the same loops in numba).

    ``t = WU [h; u; 1]`` (+ ``extra``) holds the gate pre-activations; ``s`` is its sigmoid
    part (the views ``f``, ``i``, ``o``), ``g`` the cell candidate; then
    :math:`c^+ = f \circ c + i \circ g` into ``cn``, :math:`h^+ = o \circ \tanh c^+` into
    ``hn`` (``tc`` keeps :math:`\tanh c^+` for the Jacobians).
    """
    hu1, t, s, g, f, i, o, c, _, _, tc = view
    np.dot(WU, hu1, out=t)
    if extra is not None:
        t += extra
    expit(s, out=s)
    np.tanh(g, out=g)
    np.multiply(f, c, out=cn)
    np.multiply(i, g, out=tmp)
    cn += tmp
    np.tanh(cn, out=tc)
    np.multiply(o, tc, out=hn)


_numba_missing_said = False


def _say_numba_missing_once() -> None:
    """One warning per process: numba is missing, the numpy reference kernels run."""
    global _numba_missing_said
    if _numba_missing_said:
        return
    _numba_missing_said = True
    warnings.warn(
        "numba cannot be imported: the controller runs its numpy reference kernels (the same "
        "numbers, several times slower). Install numba (a core dependency: pip install "
        "numba), or set LTV_LSTM_MPC_KERNEL=numpy to choose the reference on purpose",
        RuntimeWarning,
        stacklevel=3,
    )


class LSTMKernel:
    r"""eq. (lstm) and eq. (jacobian) writing into a :class:`Trajectory` (see module doc).

    :meth:`rollout` simulates and stores the gate activations; :meth:`jacobians` reuses
    them for the whole horizon in one batched pass; :meth:`pairs` evaluates independent
    :math:`(x_k, u_k)` pairs (not a trajectory) with the same arithmetic. No validation:
    callers check their inputs once.

    Parameters
    ----------
    model : LSTMModel
        Only its stacked gate weights are read.
    compiled : bool, optional
        Run the numba-compiled loops (default: yes where numba is installed, unless the
        environment variable ``LTV_LSTM_MPC_KERNEL`` is ``numpy``) or the numpy reference.
    """

    def __init__(self, model: LSTMModel, *, compiled: bool | None = None) -> None:
        self.n, self.m, self.p = model.n, model.m, model.p
        self.WU_raw = np.ascontiguousarray(np.hstack([model._U_gates, model._W_gates]))
        self.WU = np.ascontiguousarray(np.hstack([self.WU_raw, model._b_gates[:, None]]))
        self._scratch: dict[int, Trajectory] = {}
        #: Chosen by default (``compiled=None``), not by the caller: a controller with
        #: ``kernels="auto"`` may replace it (see :mod:`ltv_lstm_mpc.loop.kernels`).
        self.automatic = compiled is None
        if compiled is None:
            compiled = os.environ.get("LTV_LSTM_MPC_KERNEL", "numba").lower() != "numpy"
        if compiled and not _compiled.AVAILABLE:
            _say_numba_missing_once()
        #: Whether the numba-compiled loops run (``False``: the numpy reference); chosen
        #: here, once, for every kernel of the controller built on this model.
        self.compiled = bool(compiled) and _compiled.AVAILABLE
        self._no_extra = np.zeros(0)
        # the loops, chosen once: the numba twins or the numpy reference
        if self.compiled:
            self._rollout, self._pairs = self._rollout_compiled, self._pairs_compiled
            self._jacobians = self._jacobians_compiled
        else:
            self._rollout, self._pairs = self._rollout_numpy, self._pairs_numpy
            self._jacobians = self._jacobians_numpy

    def trajectory(self, N: int) -> Trajectory:
        """New preallocated buffers for a horizon of N steps."""
        return Trajectory(self.n, self.m, N)

    def _scratch_trajectory(self, N: int) -> Trajectory:
        traj = self._scratch.get(N)
        if traj is None:
            traj = self._scratch[N] = Trajectory(self.n, self.m, N)
        return traj

    def rollout(self, traj: Trajectory, k0: int, k1: int, extra: FloatArray | None = None) -> None:
        r"""Simulate steps ``k0..k1-1`` in place (inputs ``traj.u[k]`` given).

        ``extra`` is added to the gate pre-activations of every step (the observer's
        :math:`L (y - \hat y)` terms, eq. lstm_observer).
        """
        self._rollout(traj, k0, k1, extra)

    def _rollout_compiled(
        self, traj: Trajectory, k0: int, k1: int, extra: FloatArray | None
    ) -> None:
        _compiled.rollout(
            self.WU, traj.S, traj.T, traj.TC, k0, k1, self._no_extra if extra is None else extra
        )

    def _rollout_numpy(self, traj: Trajectory, k0: int, k1: int, extra: FloatArray | None) -> None:
        WU, tmp, views = self.WU, traj.tmp, traj.views
        for k in range(k0, k1):
            view = views[k]
            _cell(WU, view, view[8], view[9], tmp, extra)

    def step(self, x: FloatArray, u: FloatArray, extra: FloatArray | None = None) -> FloatArray:
        """:math:`f(x, u)` of one point (a new array), the same arithmetic as :meth:`rollout`."""
        n2, m = 2 * self.n, self.m
        traj = self._scratch_trajectory(1)
        traj.S[0, :n2] = x
        traj.S[0, n2 : n2 + m] = u
        self.rollout(traj, 0, 1, extra)
        return traj.S[1, :n2].copy()

    def simulate(self, x0: FloatArray, u_seq: FloatArray) -> FloatArray:
        """States ``(T + 1, 2n)`` from ``x0`` under ``u_seq`` ``(T, m)`` (new array)."""
        T = u_seq.shape[0]
        n2, m = 2 * self.n, self.m
        traj = self._scratch_trajectory(T)
        traj.S[0, :n2] = x0
        traj.S[:T, n2 : n2 + m] = u_seq
        self.rollout(traj, 0, T)
        return traj.S[:, :n2].copy()

    def pairs(self, x: FloatArray, u: FloatArray, *, jacobians: bool = True) -> Trajectory:
        r"""Evaluate independent pairs :math:`(x_k, u_k)`, ``x`` (K, 2n), ``u`` (K, m).

        Returns a scratch :class:`Trajectory` (valid until the next call with the same K)
        whose ``S[k, :2n]`` is :math:`x_k` and whose ``J[k]`` holds :math:`[A_k\; B_k]`
        (when ``jacobians``); the next states are in ``next_states`` of the returned
        object's ``pair_next`` attribute ``(K, 2n)``.
        """
        K = x.shape[0]
        n2, m = 2 * self.n, self.m
        traj = self._scratch_trajectory(K)
        out = getattr(traj, "pair_next", None)
        if out is None:
            out = traj.pair_next = np.empty((K, n2))  # type: ignore[attr-defined]
        S = traj.S
        S[:K, :n2] = x
        S[:K, n2 : n2 + m] = u
        self._pairs(traj, out, K)
        if jacobians:
            self.jacobians(traj)
        return traj

    def _pairs_compiled(self, traj: Trajectory, out: FloatArray, K: int) -> None:
        _compiled.pairs(self.WU, traj.S, traj.T, traj.TC, out, K)

    def _pairs_numpy(self, traj: Trajectory, out: FloatArray, K: int) -> None:
        n, WU, tmp = self.n, self.WU, traj.tmp
        for k in range(K):
            _cell(WU, traj.views[k], out[k, :n], out[k, n:], tmp, None)

    def jacobians(self, traj: Trajectory) -> None:
        r"""Batched :math:`[A_k\; B_k] = \partial f / \partial [c; h; u]` at the stored steps."""
        self._jacobians(traj)

    def _jacobians_compiled(self, traj: Trajectory) -> None:
        _compiled.jacobians(self.WU_raw, traj.S, traj.T, traj.TC, traj.J)

    def _jacobians_numpy(self, traj: Trajectory) -> None:
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
