"""Leaving Python: the controller as dependency-free C99.

:mod:`.c_model`: the LSTM model, its observer, the reference calculator, the tightening
formulas, the MPC's subproblem with DAQP and the whole controller step; :mod:`.sil`: the
export on the host through ctypes; :mod:`.c_engine`: the controller's step engine on it,
``OffsetFreeController(engine="c")``; :mod:`.package`: the C project for integrators
(``ltv-lstm-mpc export-c``); :mod:`.pil`: a replay on a Cortex-M7 under QEMU.
"""

from ltv_lstm_mpc.export.c_model import ExportedC, export_model_c
from ltv_lstm_mpc.export.package import export_controller_c

__all__ = ["ExportedC", "export_controller_c", "export_model_c"]
