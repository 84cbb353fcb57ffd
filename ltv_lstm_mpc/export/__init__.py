"""Leaving Python: the controller's parts as dependency-free C99 (:mod:`.c_model`: the
LSTM model and its observer, the first part of the C export)."""

from ltv_lstm_mpc.export.c_model import ExportedC, export_model_c

__all__ = ["ExportedC", "export_model_c"]
