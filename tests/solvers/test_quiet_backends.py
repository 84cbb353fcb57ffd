"""Backends print nothing of their own: HiGHS' banner (printed from C when the first
``Highs`` object of a process is made, whatever ``verbose`` says) does not reach stdout."""

from __future__ import annotations

import subprocess
import sys

from optional_extras import requires_solver


@requires_solver("cvxpy:HIGHS")
def test_cvxpy_highs_prints_no_banner() -> None:
    code = (
        "import numpy as np\n"
        "from ltv_lstm_mpc.solvers import DenseQP, solve\n"
        "qp = DenseQP(H=np.eye(2), f=np.array([1.0, -1.0]), A=np.zeros((0, 2)), lo=np.zeros(0),"
        " up=np.zeros(0), lb=-np.ones(2), ub=np.ones(2))\n"
        "solution = solve(qp.to_convex_problem(), 'cvxpy:HIGHS')\n"
        "print('status', solution.status.value, round(float(solution.z[0]), 6))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "HiGHS" not in result.stdout and "HiGHS" not in result.stderr
    assert result.stdout.split() == ["status", "optimal", "-1.0"]  # argmin of z^2/2 + z
