r""":class:`ExactNMPC`: the RTI core with the nonlinear transcription (CasADi + IPOPT).

The accuracy reference of the RTI answers; the transcription itself (the NLP of eq.
(optimization) in multiple-shooting form) is :class:`~ltv_lstm_mpc.mpc.nmpc.NonlinearTranscription`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from ltv_lstm_mpc.certificates.certify import Certification
from ltv_lstm_mpc.lstm.model import LSTMModel
from ltv_lstm_mpc.mpc.config import MPCConfig, require_config
from ltv_lstm_mpc.mpc.rti import RobustMPC
from ltv_lstm_mpc.validation import expect_instance, expect_real

__all__ = ["ExactNMPC"]


class ExactNMPC(RobustMPC):
    r"""Exact NMPC of eq. (optimization) with CasADi + IPOPT (the accuracy reference).

    :class:`~ltv_lstm_mpc.RobustMPC` with the nonlinear transcription
    (``MPCConfig(solver="ipopt")``): the same front-end, prechecks, fallback chain,
    validation, residuals and records as every other transcription. Usable as
    ``OffsetFreeController(model, MPCConfig(solver="ipopt"))``.

    Parameters
    ----------
    model : LSTMModel
    config : MPCConfig, optional
        ``solver`` is set to ``"ipopt"`` (``transcription`` to ``"nonlinear"``).
    certification : Certification, optional
    smoothing : float
        :math:`\varepsilon` of the smoothed norms.
    ipopt_options : dict, optional
        Extra IPOPT options, merged over ``config.solver_settings``.
    """

    def __init__(
        self,
        model: LSTMModel,
        config: MPCConfig | None = None,
        *,
        certification: Certification | None = None,
        smoothing: float = 1e-8,
        ipopt_options: dict[str, Any] | None = None,
    ) -> None:
        config = require_config(config)
        if ipopt_options is not None:
            expect_instance("ipopt_options", ipopt_options, dict, expected="a dict or None")
        expect_real("smoothing", smoothing, low=0.0, low_open=True)
        config = replace(
            config,
            solver="ipopt",
            transcription="nonlinear",
            solver_settings={**config.solver_settings, **(ipopt_options or {})},
        )
        super().__init__(model, config, certification=certification, smoothing=smoothing)

    @property
    def ipopt_iterations(self) -> int:
        """IPOPT iterations of the last call (all NLPs solved in it)."""
        return self.qp_iterations
