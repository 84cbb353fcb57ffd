"""Reproduce the paper's five closed-loop simulations (Section V, Figs. 3-7).

Writes ``<scenario>.png``, ``<scenario>.csv``, ``<scenario>.json`` and ``summary.json`` to
``--out`` and prints the summary table with the certificate numbers next to the paper's.
Same as ``ltv-lstm-mpc reproduce``; see ``ltv_lstm_mpc/scenarios.py`` for the schedules.

Run: ``python experiments/paper_scenarios.py --out results [--only 1_ 4_] [--solver osqp]``.
"""

from __future__ import annotations

import sys

from ltv_lstm_mpc.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["reproduce", *sys.argv[1:]]))
