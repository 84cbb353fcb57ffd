"""The layout of ``<prefix>_socp``: one exact-cone problem of the C export's
``daqp:socp`` step and its SQP's buffers (``templates/socp.c.in``), the C twin of
:data:`~ltv_lstm_mpc.solvers.socp_sqp.SocpWorkspace`. One table, :data:`SOCP_STRUCT`, gives
the C declaration (:func:`socp_declaration`, rendered by
:func:`~ltv_lstm_mpc.export.c_model.export_model_c`) and the software-in-the-loop's ctypes
mirror (:func:`~ltv_lstm_mpc.export.sil.socp_type`)."""

from __future__ import annotations

__all__ = [
    "SOCP_PROBLEMS",
    "SOCP_SIZE_KEYS",
    "SOCP_STRUCT",
    "socp_declaration",
    "socp_length",
    "socp_sizes",
]

#: The fields of ``<prefix>_socp`` (the exact cones' SQP buffers, ``socp.c.in``) in order:
#: (name, C type, length), the length in the sizes of :func:`socp_sizes` ("n", "m", "f",
#: "c", "k", "r", "R": the largest problem's variables, rows, cone rows, cones, n + m + c,
#: the infeasibility check's kept cutting planes and the iterates they are kept of). The
#: C declaration (:func:`socp_declaration`) and the ctypes mirror of the SIL
#: (:func:`ltv_lstm_mpc.export.sil.socp_type`) are both made from it.
SOCP_STRUCT = (
    ("n", "int", "1"), ("m", "int", "1"), ("cones", "int", "1"), ("cone_rows", "int", "c+1"),
    ("H", "real", "n*n"), ("f", "real", "n"), ("A", "real", "m*n"), ("lb", "real", "n"),
    ("ub", "real", "n"), ("lo", "real", "m"), ("up", "real", "m"), ("F", "real", "f*n"),
    ("g", "real", "f"), ("e", "real", "c*n"), ("offsets", "real", "c"), ("z", "real", "n"),
    ("mu", "real", "c"), ("lam", "real", "k"), ("hessian", "real", "n*n"),
    ("A_k", "real", "(m+c+r)*n"), ("bupper", "real", "k+r"), ("blower", "real", "k+r"),
    ("sense", "int", "k+r"), ("x", "real", "n"), ("v", "real", "f"), ("w", "real", "n"),
    ("linear", "real", "n"), ("gradients", "real", "c*n"), ("gradient_bounds", "real", "c"),
    ("kept", "int", "m"), ("lam_k", "real", "k+r"), ("row_values", "real", "m"),
    ("row_norms", "real", "m"), ("epigraph", "int", "c"), ("eliminated", "int", "c"),
    ("first_active", "int", "c"), ("reduced_index", "int", "n"), ("tau", "real", "c*n"),
    ("tau_offset", "real", "c"), ("coupled", "real", "c*n"),
    ("reduced_hessian", "real", "n*n"), ("reduced_linear", "real", "n"),
    ("reduced_rows", "real", "(m+c)*n"), ("reduced_upper", "real", "k"),
    ("reduced_lower", "real", "k"), ("reduced_sense", "int", "k"), ("reduced_x", "real", "n"),
    ("reduced_lam", "real", "k"), ("direction", "real", "n"), ("regularized", "int", "2"),
    ("cuts", "real", "r*n"), ("cut_bounds", "real", "r"), ("cut_points", "real", "R*n"),
    ("cut_state", "int", "3"), ("saved_x", "real", "n"), ("plane_slack", "real", "c"),
)  # fmt: skip
#: The names of :func:`socp_sizes`, in the order of ``ExportedC.socp_sizes``.
SOCP_SIZE_KEYS = ("n", "m", "f", "c", "k", "r", "R")
#: The exact-cone problems a cone export holds, in the order of ``<prefix>_mpc_workspace``'s
#: ``socp`` array: the nominal one (solved once a step; a failed solve's status is read
#: from it), the infeasibility policy's.
SOCP_PROBLEMS = ("nominal", "policy")


def socp_sizes(N: int, n: int, m: int, p: int, policy: str) -> dict[str, int]:
    """The sizes of ``<prefix>_socp``'s arrays for horizon ``N``, a model of ``n`` units,
    ``m`` inputs, ``p`` outputs and the infeasibility ``policy``: the largest of the
    exact-cone problems' variables ``n`` (``[du, t_c, t_h]``, with ``"soft"`` the output
    slacks and ``s_T``), rows ``m`` (the outputs i = 1..N-1, twice with ``"soft"``; at
    least 4), cone rows ``f`` (2n + 2) and cones ``c`` (3); ``k`` = n + m + c; ``R``
    (:data:`~ltv_lstm_mpc.solvers.socp_sqp.CUT_ROUNDS`) iterates' cutting planes kept,
    ``r`` = R c of them."""
    n_out = (N - 1) * p
    variables = N * m + 2 + (n_out + 1 if policy == "soft" else 0)
    # (at least 4: gcc's -Warray-bounds reads the four-row pass of sqp_row_values at
    # shorter arrays, where it never runs)
    rows = max(n_out * (2 if policy == "soft" else 1), 4)
    sizes = {"n": variables, "m": rows, "f": 2 * n + 2, "c": 3}
    sizes["k"] = variables + rows + 3
    from ltv_lstm_mpc.solvers.socp_sqp import CUT_ROUNDS

    sizes["R"] = CUT_ROUNDS
    sizes["r"] = CUT_ROUNDS * sizes["c"]
    return sizes


def socp_length(length: str, sizes: dict[str, int]) -> int:
    """A :data:`SOCP_STRUCT` length for ``sizes``."""
    total = 1
    for factor in length.split("*"):  # a product of sums of sizes and integers
        terms = factor.strip("()").split("+")
        total *= sum(int(term) if term.isdigit() else sizes[term] for term in terms)
    return total


def socp_declaration(prefix: str, sizes: dict[str, int]) -> str:
    """The C declaration of ``<prefix>_socp`` (:data:`SOCP_STRUCT` at ``sizes``)."""
    lines = [
        "",
        f"/** One exact-cone problem of {prefix}_feedback on daqp:socp and its SQP's buffers",
        " * (solvers/socp_sqp.py's SocpWorkspace): min 1/2 z'Hz + f'z s.t. lo <= A z <= up,",
        " * lb <= z <= ub, ||F_j z + g_j|| <= e_j'z + f_j (j < cones), f_j in offsets. The",
        " * arrays are packed with the problem's own sizes n, m (H: n x n row-major, A: m x n,",
        " * F: the cones' rows in turn, cone j rows cone_rows[j] .. cone_rows[j + 1] - 1) and",
        " * sized for the largest of the controller's problems. */",
        "typedef struct {",
    ]
    for name, kind, length in SOCP_STRUCT:
        ctype = f"{prefix}_real" if kind == "real" else "int"
        count = socp_length(length, sizes)
        lines.append(f"    {ctype} {name}" + ("" if length == "1" else f"[{count}]") + ";")
    lines.append(f"}} {prefix}_socp;")
    return "\n".join(lines) + "\n"
