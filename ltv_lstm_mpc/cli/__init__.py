"""The ``ltv-lstm-mpc`` command line (``certify``, ``reproduce``, ``simulate``, ``bench``, ...)."""

from ltv_lstm_mpc.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
