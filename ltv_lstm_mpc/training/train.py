r"""delta-ISS LSTM identification with torch (paper Section V, "LSTM model identification").

This is the only module of :mod:`ltv_lstm_mpc` that imports torch, and only inside functions:
``import ltv_lstm_mpc.training.train`` works without torch; calling :func:`train` or
:func:`torch_residuals` without it raises an ImportError saying how to install it.

Loss (paper, per batch)
-----------------------
.. math::

    L = \frac{1}{N} \sum_k \|y_k - y_{real,k}\|^2 + \lambda_1 \max\{r_1, 0\}
        + \lambda_1 \max\{r_2, 0\} + \lambda_2 \min\{r_1, 0\} + \lambda_2 \min\{r_2, 0\}

in normalized units, with the Remark 1 residuals :math:`r_1, r_2` computed differentiably
(:func:`torch_residuals`; identical to
:func:`ltv_lstm_mpc.delta_iss_certificate`
to rounding in float64, including the paper notes 2.2 correction of :math:`\alpha`).

Design choices the paper leaves open
------------------------------------
* **Initial state.** Every identification sequence starts with the plant at its nominal steady
  state (q3 = 15.6 mL/s, :mod:`ltv_lstm_mpc.training.datasets`), so every sequence starts the
  LSTM at its
  equilibrium for that constant input, :math:`x_0 = f(x_0, N_u(15.6))`. In training this is
  approximated differentiably (``equilibrium_steps`` iterations without gradient, then
  ``equilibrium_grad_steps`` with gradient); in evaluation it is
  :meth:`ltv_lstm_mpc.LSTMModel.equilibrium` (exact). An optional ``washout``
  excludes the
  first samples of each sequence from the loss (default 0: the initial state is consistent).
* **Output alignment (paper notes 1).** The model output at time k is :math:`W_y h_k + b_y`, with
  :math:`h_k` the state after reading :math:`u_0..u_{k-1}`. torch's ``nn.LSTM`` returns
  :math:`h_{k+1}` after reading :math:`u_k`, so the prediction sequence is
  :math:`[h_0, \text{out}_0, \dots, \text{out}_{T-2}]` mapped through the linear layer.
* **Truncated back-propagation through time.** Each epoch runs the training sequences (in
  batches of ``batch_size`` sequences, shuffled) through consecutive chunks of ``truncation``
  samples, carrying the state from chunk to chunk (detached) and taking one Adam step per chunk.
  The whole sequence is thus simulated from its true initial state (no state is guessed), and an
  epoch makes several optimizer steps.
* **Stopping rule (paper).** After ``epochs`` epochs training stops only if the current weights
  are certified delta-ISS (numpy certificate on the exported float64 weights,
  :math:`\rho(A_\delta) < 1`) and an eligible checkpoint exists; otherwise it continues, at
  most ``max_extra_epochs`` more, with :math:`\lambda_1, \lambda_2` doubled every
  ``escalate_every`` of them (:func:`escalation_factor`; a run that stops at the planned
  epochs is untouched). If no evaluated weights were ever eligible,
  :class:`TrainingError` is raised, naming the first selection constraint that failed
  (Assumption 2, certify, the :math:`\rho_s` bound, the set-point interval) and its number.
* **Model selection.** At every evaluation the exported float64 model is simulated on the
  validation split from its exact equilibrium (the FIT below). A checkpoint is eligible if
  it passes :func:`~ltv_lstm_mpc.certify` with the paper's settings
  (Assumption 2, Lemma 2, Theorem 2, tightening), has a non-empty admissible set-point
  interval (Assumption 5) at the paper's :math:`d_{max} = 0.1` and, with
  ``selection_rho_s_max``, :math:`\rho_s` at most that; the exported model is the
  eligible one with the best validation FIT. Where no checkpoint meets the
  :math:`\rho_s` bound (tuned on the pH data) the best certified one with a non-empty
  interval is kept and the report says so (``selection_fallback``); one with an empty
  interval only with ``allow_empty_interval``. The test split is evaluated once, on the
  exported model.
* **Checks before training.** :func:`preflight` compares the output constraint with the
  data's output range (no model has an admissible set-point where the normalized
  constraint is at most :math:`4 d_{max}` wide) and states the data's first-order time
  constant in samples (slow dynamics per sample push :math:`\rho_s` towards 1).
* **Loss schedule.** ``delta_iss_margin`` switches the :math:`\lambda_2` margin term off
  while :math:`\rho(A_\delta) \le 1 - margin` (with it always on, the margin keeps
  growing at the expense of the fit: measured in ``experiments/training_log.md``);
  ``lr_warmup_epochs``, ``lr_final_factor`` (cosine) and ``grad_clip_norm`` shape the
  optimizer steps.
* **FIT.** :math:`100 (1 - \|y_{real} - y\| / \|y_{real} - \bar y_{real}\|)` on the physical
  outputs of all sequences of a split concatenated (one number per split), simulated with
  :meth:`~ltv_lstm_mpc.LSTMModel.simulate` on the exported model from the equilibrium
  above. The per-sequence FITs are reported too.
* **Several inputs and outputs** (e.g. the quadruple tank, data of shape (S, T, m) and
  (S, T, p)): the network has m inputs and p outputs, the MSE averages over the outputs
  (normalized units), the initial equilibrium is that of the data's ``u_phi_initial``, the
  FIT is computed per output (``fit_per_output``) and ``fit`` is the smallest of them (also
  the validation number the best weights are chosen by). The exported model carries the
  data's output constraint (``y_phi_constraint`` in the metadata; the pH data: the paper's
  [6, 9] pH) and sampling time ``Ts``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ltv_lstm_mpc.certificates.stability import (
    delta_iss_certificate,
    incremental_lyapunov_certificate,
)
from ltv_lstm_mpc.exceptions import InvalidValueError, LtvMpcError
from ltv_lstm_mpc.lstm.model import LSTMModel, Normalization
from ltv_lstm_mpc.training.datasets import (
    SPLITS,
    IdentificationDataset,
    initial_input,
    input_coverage,
    simulate_sequences,
)

__all__ = [
    "SELECTION_POOLS",
    "TORCH_INSTALL_HINT",
    "CheckpointCheck",
    "TrainingConfig",
    "TrainingError",
    "TrainingResult",
    "check_checkpoint",
    "escalation_factor",
    "evaluate_model",
    "fit_index",
    "guarantee_numbers",
    "learning_rate",
    "margin_term_active",
    "plot_prediction",
    "plot_training_curves",
    "preflight",
    "selection_certificate",
    "torch_residuals",
    "train",
    "write_history_csv",
]

FloatArray = NDArray[np.float64]

TORCH_INSTALL_HINT = (
    "training needs PyTorch, which is an optional dependency: install the CPU wheel with "
    '`pip install torch==2.13.0`, then `pip install -e ".[train]"`'
)
CHECKPOINT_NAME = "checkpoint.pt"


class TrainingError(LtvMpcError, RuntimeError):
    """Training could not produce a certified delta-ISS model (or was misconfigured)."""


def _import_torch() -> Any:
    try:
        import torch
    except ImportError as error:  # pragma: no cover - depends on the environment
        raise ImportError(TORCH_INSTALL_HINT) from error
    return torch


# --------------------------------------------------------------------------- config
@dataclass(frozen=True)
class TrainingConfig:
    """Settings of :func:`train`; the defaults reproduce the paper where it fixes a value.

    Attributes
    ----------
    n : int
        Number of LSTM neurons (paper: 5).
    lambda1, lambda2 : float
        Weights of the delta-ISS terms of the loss (paper: 0.03, 0.02).
    lr : float
        Adam learning rate (paper: 1e-3).
    epochs : int
        Planned epochs (paper: 1000).
    max_extra_epochs : int
        Extra epochs allowed when the model is not delta-ISS after ``epochs`` (stopping rule).
    seed : int
        Seeds torch (weight initialization) and numpy (batch shuffling).
    truncation : int
        Chunk length of truncated back-propagation through time (0: whole sequences). Default
        100 samples: 15 Adam steps per epoch over the 1500-sample sequences (not in the paper),
        about three 2 % settling times of the pH plant's step responses (33-38 samples,
        :func:`~ltv_lstm_mpc.training.datasets.step_settling_times`; the quadruple tank's
        slowest is 48), so each chunk sees the responses to its inputs settle.
        Measured (validation FIT): chunks of 250 with torch's default initialization, 64 %
        after 100 epochs; chunks of 100, 91.4 % after 200 epochs, 94.2 % with
        ``forget_bias_init = 2``.
    batch_size : int
        Sequences per batch (0: all training sequences in one batch).
    washout : int
        Samples at the start of each sequence excluded from the loss (default 0: the initial
        state is the consistent equilibrium, see the module docstring).
    equilibrium_steps, equilibrium_grad_steps : int
        Iterations of the initial-equilibrium approximation without / with gradient.
    forget_bias_init : float or None
        Initial forget-gate bias (``bias_ih``; ``bias_hh`` set to 0); None keeps torch's
        default. Default 2.0 (not in the paper): a slow initial memory like the plant's
        (time constants 9-26 samples). Its sign does not matter for the certificate, which
        uses absolute values; the delta-ISS penalty shrinks it as needed.
    lr_final_factor : float
        Cosine decay of the learning rate from ``lr`` to ``lr * lr_final_factor`` over the
        planned epochs after the warm-up (1.0: constant, the paper's Adam setting).
    lr_warmup_epochs : int
        Linear learning-rate warm-up from ``lr / lr_warmup_epochs`` to ``lr`` over the first
        epochs (0: none); the cosine decay then runs over the remaining planned epochs.
    delta_iss_margin : float or None
        Loss schedule of the margin term. None (default, the paper): the
        :math:`\\lambda_2 \\min\\{r_1, 0\\} + \\lambda_2 \\min\\{r_2, 0\\}` term is always on and
        keeps widening the delta-ISS margin of Assumption 2 (eq. delta_iss_matrix) for as long
        as training runs, trading fit for margin. A number ``margin`` in (0, 1): the term is
        on only while the certificate of the last epoch has
        :math:`\\rho(A_\\delta) > 1 - margin`; once it holds with that margin the loss is
        the MSE plus the :math:`\\lambda_1` terms (zero while :math:`r_1, r_2 < 0`), and the
        term re-engages if the margin is lost. The :math:`\\lambda_1` terms are never
        switched off.
    grad_clip_norm : float
        Clip the global gradient norm of each Adam step to this value
        (``torch.nn.utils.clip_grad_norm_``; 0: no clipping, the default).
    selection_rho_s_max : float or None
        Model selection: a checkpoint is eligible only if its :math:`\\rho_s` (Lemma 2, eq.
        incremental_lyap_neg_def, with ``Q_s``) is at most this value (None: any
        :math:`\\rho_s`). Every eligible checkpoint must also pass the library's
        :func:`~ltv_lstm_mpc.certify` with the paper's settings
        (Assumption 2 :math:`\\rho(A_\\delta) < 1`, Lemma 2, Theorem 2, tightening); among
        them the best validation FIT is kept. Training goes on after the planned epochs
        (at most ``max_extra_epochs``) until the current weights are delta-ISS and an
        eligible checkpoint exists.
    threads : int
        ``torch.set_num_threads``. Default 1: for n = 5 the matrices are tiny and a second
        thread only adds synchronization (measured 0.41 vs 0.47 s per epoch on an idle 2-core
        VM, and about 10x slower with 2 threads when other processes load the CPU).
    dtype : str
        ``"float64"`` or ``"float32"`` for training (export and certificates are float64).
    checkpoint_every : int
        Epochs between checkpoints (0: never).
    eval_every : int
        Epochs between validation evaluations (best-model tracking, progress bar).
    u_max : float
        Input bound of the delta-ISS certificate (normalized units, 1).
    Q_s : float
        :math:`Q_s = q I_2` of Lemma 2 for the reported :math:`\\rho_s` (paper: 1000).
    selection_fallback : bool
        When no checkpoint meets ``selection_rho_s_max`` (a bound tuned on the pH data: a
        plant whose data need slower dynamics may never reach it), select the best
        validation FIT among the certified checkpoints whose admissible set-point interval
        (Assumption 5) is non-empty, whatever their :math:`\\rho_s`; the report
        (``selection_outcome``) and ``train`` say so. False: no model (a
        :class:`TrainingError` naming the bound) in that case. Default True.
    escalate_every : int
        The extra epochs of the stopping rule run only while no checkpoint qualifies (not
        delta-ISS, or no eligible checkpoint); during them :math:`\\lambda_1` and
        :math:`\\lambda_2` are doubled at once and again every ``escalate_every`` epochs
        (:func:`escalation_factor`; 0: never, the paper's rule). Runs that stop at the
        planned epochs (the shipped models' runs) are unaffected. Default 50.
    allow_empty_interval : bool
        Also accept a checkpoint whose admissible set-point interval of Assumption 5 at the
        paper's :math:`d_{max} = 0.1` is empty (such a model is refused by ``simulate`` at
        that :math:`d_{max}`), when no checkpoint has a non-empty one. Default False:
        :func:`train` raises :class:`TrainingError` instead of writing it.
    """

    n: int = 5
    lambda1: float = 0.03
    lambda2: float = 0.02
    lr: float = 1e-3
    epochs: int = 1000
    max_extra_epochs: int = 1000
    seed: int = 0
    truncation: int = 100
    batch_size: int = 0
    washout: int = 0
    equilibrium_steps: int = 400
    equilibrium_grad_steps: int = 20
    forget_bias_init: float | None = 2.0
    lr_final_factor: float = 1.0
    lr_warmup_epochs: int = 0
    delta_iss_margin: float | None = None
    grad_clip_norm: float = 0.0
    selection_rho_s_max: float | None = None
    threads: int = 1
    dtype: str = "float64"
    checkpoint_every: int = 50
    eval_every: int = 1
    u_max: float = 1.0
    Q_s: float = 1000.0
    selection_fallback: bool = True
    allow_empty_interval: bool = False
    escalate_every: int = 50

    def __post_init__(self) -> None:
        positive_ints = ("n", "epochs", "threads", "eval_every")
        for name in positive_ints:
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise InvalidValueError(f"{name} must be a positive integer, got {value!r}")
        nonnegative_ints = (
            "max_extra_epochs",
            "seed",
            "truncation",
            "batch_size",
            "washout",
            "equilibrium_steps",
            "equilibrium_grad_steps",
            "checkpoint_every",
            "lr_warmup_epochs",
            "escalate_every",
        )
        for name in nonnegative_ints:
            value = getattr(self, name)
            if not isinstance(value, int) or value < 0:
                raise InvalidValueError(f"{name} must be a nonnegative integer, got {value!r}")
        for name in (
            "lambda1",
            "lambda2",
            "lr",
            "u_max",
            "Q_s",
            "lr_final_factor",
            "grad_clip_norm",
        ):
            value = float(getattr(self, name))
            if (
                not math.isfinite(value)
                or value < 0
                or (name in ("lr", "u_max", "Q_s") and value == 0)
            ):
                raise InvalidValueError(f"{name} must be a finite positive number, got {value!r}")
        for name in ("delta_iss_margin", "selection_rho_s_max"):
            value = getattr(self, name)
            if value is not None and not (
                isinstance(value, (int, float)) and 0.0 < float(value) < 1.0
            ):
                raise InvalidValueError(f"{name} must be None or in (0, 1), got {value!r}")
        for name in ("selection_fallback", "allow_empty_interval"):
            if not isinstance(getattr(self, name), bool):
                raise InvalidValueError(
                    f"{name} must be True or False, got {getattr(self, name)!r}"
                )
        if self.dtype not in ("float64", "float32"):
            raise InvalidValueError(f"dtype must be 'float64' or 'float32', got {self.dtype!r}")

    @classmethod
    def fidelity(cls, **overrides: Any) -> TrainingConfig:
        r"""Settings measured in ``experiments/training_log.md`` (runs r02-r07):
        1500 epochs, learning rate :math:`3 \cdot 10^{-3}` with a 20-epoch warm-up and a
        cosine decay to 3 %, the :math:`\lambda_2` margin term off while
        :math:`\rho(A_\delta) \le 0.88` (``delta_iss_margin = 0.12``), and selection among
        the checkpoints with :math:`\rho_s \le 0.92` (:math:`Q_s = 1000 I`). On the pH
        data of ``generate-data --levels 11 --hold-from-plant`` (n = 5, one core, about
        8 minutes) they reach test FIT 97.8 % with :math:`\rho_s` 0.913 (run r06; 2000
        epochs: 97.8-98.0 %), against the paper's settings' 95.0 % and 0.921.

        Parameters
        ----------
        **overrides
            Fields to set on top (e.g. ``seed``, ``n``).
        """
        values: dict[str, Any] = {
            "epochs": 1500,
            "max_extra_epochs": 500,
            "lr": 3e-3,
            "lr_warmup_epochs": 20,
            "lr_final_factor": 0.03,
            "delta_iss_margin": 0.12,
            "selection_rho_s_max": 0.92,
        }
        values.update(overrides)
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (JSON-serializable)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> TrainingConfig:
        """Inverse of :meth:`to_dict`; rejects unknown keys."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise InvalidValueError(
                f"unknown TrainingConfig keys {unknown}; allowed: {sorted(known)}"
            )
        return cls(**values)


@dataclass(frozen=True)
class TrainingResult:
    """What :func:`train` produced.

    Attributes
    ----------
    model : LSTMModel
        The exported certified model (float64, with normalization).
    report : dict
        The JSON report (also written to ``report_path``).
    model_path, report_path, plot_path : Path
        Files written in ``out_dir`` (``plot_path`` is None if matplotlib failed).
    history : list of dict
        Per-evaluation records (epoch, loss, mse, r1, r2, rho_A_delta, rho_s, fit_val,
        certified, margin_term, lr).
    curves_path : Path or None
        PNG of the validation FIT, :math:`\\rho(A_\\delta)` and :math:`\\rho_s` against the
        epoch (None if matplotlib failed).
    """

    model: LSTMModel
    report: dict[str, Any]
    model_path: Path
    report_path: Path
    plot_path: Path | None
    history: list[dict[str, float]] = field(default_factory=list)
    curves_path: Path | None = None


# ------------------------------------------------------------------------ metrics
def fit_index(y_real: ArrayLike, y: ArrayLike) -> float:
    r"""FIT index of the paper: :math:`100 (1 - \|y_{real} - y\| / \|y_{real} - \bar y_{real}\|)`.

    Arrays of any (equal) shape are flattened (so a split's sequences are concatenated).
    """
    real = np.asarray(y_real, dtype=np.float64).ravel()
    pred = np.asarray(y, dtype=np.float64).ravel()
    if real.shape != pred.shape:
        raise InvalidValueError(f"y_real {real.shape} and y {pred.shape} must have equal size")
    denominator = float(np.linalg.norm(real - real.mean()))
    if denominator == 0.0:
        raise InvalidValueError("FIT is undefined for a constant y_real")
    return 100.0 * (1.0 - float(np.linalg.norm(real - pred)) / denominator)


def evaluate_model(
    model: LSTMModel, dataset: IdentificationDataset, splits: tuple[str, ...] = SPLITS
) -> dict[str, dict[str, Any]]:
    """FIT per split (concatenated sequences), per output and per sequence (numpy simulation).

    Returns ``{split: {"fit": float, "fit_per_output": [...], "fit_per_sequence": [...]}}``;
    with several outputs ``fit`` is the smallest per-output FIT and ``fit_per_sequence``
    holds one list per sequence (one FIT per output).
    """
    u0 = initial_input(dataset.metadata)
    result: dict[str, dict[str, Any]] = {}
    for name in splits:
        u, y = dataset.split(name)
        if u.shape[0] == 0:
            continue
        pred = simulate_sequences(model, u, u0)
        if y.ndim == 2:
            result[name] = {
                "fit": fit_index(y, pred),
                "fit_per_output": [fit_index(y, pred)],
                "fit_per_sequence": [fit_index(y[i], pred[i]) for i in range(y.shape[0])],
            }
            continue
        per_output = [fit_index(y[..., j], pred[..., j]) for j in range(y.shape[2])]
        result[name] = {
            "fit": min(per_output),
            "fit_per_output": per_output,
            "fit_per_sequence": [
                [fit_index(y[i, :, j], pred[i, :, j]) for j in range(y.shape[2])]
                for i in range(y.shape[0])
            ],
        }
    return result


# ------------------------------------------------------------------ torch pieces
def _gate_blocks(lstm: Any) -> dict[str, tuple[Any, Any, Any]]:
    """(W, U, b) per gate f, i, o, c from a torch nn.LSTM (torch order i, f, g, o)."""
    n = lstm.hidden_size
    w_ih, w_hh = lstm.weight_ih_l0, lstm.weight_hh_l0
    bias = lstm.bias_ih_l0 + lstm.bias_hh_l0
    rows = {
        "i": slice(0, n),
        "f": slice(n, 2 * n),
        "c": slice(2 * n, 3 * n),
        "o": slice(3 * n, 4 * n),
    }
    return {g: (w_ih[r], w_hh[r], bias[r]) for g, r in rows.items()}


def torch_residuals(blocks: dict[str, tuple[Any, Any, Any]], u_max: float = 1.0) -> tuple[Any, Any]:
    r"""Differentiable residuals :math:`r_1, r_2` of Remark 1 (paper notes 2.2 alpha).

    Parameters
    ----------
    blocks : dict
        ``{"f": (W_f, U_f, b_f), "i": ..., "o": ..., "c": ...}`` torch tensors with shapes
        (n, m), (n, n), (n,).
    u_max : float
        Input bound of the certificate.

    Returns
    -------
    r1, r2 : torch scalar tensors
        Equal (to rounding) to :func:`ltv_lstm_mpc.delta_iss_certificate`'s.
    """
    torch = _import_torch()

    def row_norm(W: Any, U: Any, b: Any) -> Any:
        return torch.max((W.abs() * u_max).sum(dim=1) + U.abs().sum(dim=1) + b.abs())

    def spectral(M: Any) -> Any:
        return torch.linalg.matrix_norm(M, ord=2)

    W_f, U_f, b_f = blocks["f"]
    W_i, U_i, b_i = blocks["i"]
    W_o, U_o, b_o = blocks["o"]
    W_c, U_c, b_c = blocks["c"]

    def sigmoid(z: Any) -> Any:
        # Same formula as the numpy certificate, so both round alike near sigma_f -> 1.
        return 0.5 * (1.0 + torch.tanh(0.5 * z))

    sigma_f = sigmoid(row_norm(W_f, U_f, b_f))
    sigma_i = sigmoid(row_norm(W_i, U_i, b_i))
    sigma_o = sigmoid(row_norm(W_o, U_o, b_o))
    sigma_c = torch.tanh(row_norm(W_c, U_c, b_c))
    c_bound = sigma_i * sigma_c / (1.0 - sigma_f)
    sigma_x = torch.tanh(c_bound)
    norm_U_o = spectral(U_o)
    alpha = (
        0.25 * spectral(U_f) * c_bound + sigma_i * spectral(U_c) + 0.25 * spectral(U_i) * sigma_c
    )
    r1 = (
        -1.0
        + sigma_f
        + alpha * sigma_o
        + 0.25 * sigma_x * norm_U_o
        - 0.25 * sigma_f * sigma_x * norm_U_o
    )
    r2 = 0.25 * sigma_f * sigma_x * norm_U_o - 1.0
    return r1, r2


def _delta_iss_penalty(
    r1: Any, r2: Any, config: TrainingConfig, margin_term: bool = True, scale: float = 1.0
) -> Any:
    r"""The delta-ISS terms of the loss: :math:`\lambda_1 \max\{r_j, 0\}` always, the margin
    reward :math:`\lambda_2 \min\{r_j, 0\}` only when ``margin_term`` (see
    ``TrainingConfig.delta_iss_margin``); both weights times ``scale``
    (:func:`escalation_factor`)."""
    torch = _import_torch()
    zero = torch.zeros((), dtype=r1.dtype)
    lambda1, lambda2 = config.lambda1, config.lambda2
    if scale != 1.0:
        lambda1, lambda2 = lambda1 * scale, lambda2 * scale
    penalty = lambda1 * torch.maximum(r1, zero) + lambda1 * torch.maximum(r2, zero)
    if margin_term:
        penalty = penalty + lambda2 * torch.minimum(r1, zero) + lambda2 * torch.minimum(r2, zero)
    return penalty


def escalation_factor(epoch: int, config: TrainingConfig) -> float:
    r"""Factor on :math:`\lambda_1, \lambda_2` in epoch ``epoch`` (0-based): 1 in the
    planned epochs; in the extra epochs of the stopping rule (which run only while no
    checkpoint qualifies) it doubles every ``escalate_every`` epochs (0: never, the paper's
    rule), so the delta-ISS terms eventually outweigh a fit that wants slower dynamics than
    Assumption 2 and the selection allow."""
    if config.escalate_every == 0 or epoch < config.epochs:
        return 1.0
    return float(2.0 ** ((epoch - config.epochs) // config.escalate_every + 1))


def margin_term_active(rho_A_delta: float, config: TrainingConfig) -> bool:
    r"""Whether the :math:`\lambda_2` margin term of the loss is on, given the
    :math:`\rho(A_\delta)` of the last certificate (Assumption 2): always without a
    ``delta_iss_margin`` (the paper), else while :math:`\rho(A_\delta) > 1 - margin`."""
    if config.delta_iss_margin is None:
        return True
    return not rho_A_delta <= 1.0 - config.delta_iss_margin


def learning_rate(epoch: int, config: TrainingConfig) -> float:
    """Learning rate of ``epoch`` (0-based): linear warm-up over ``lr_warmup_epochs``, then a
    cosine decay to ``lr * lr_final_factor`` at the last planned epoch, then constant."""
    warmup = min(config.lr_warmup_epochs, config.epochs)
    if epoch < warmup:
        return config.lr * (epoch + 1) / warmup
    span = max(config.epochs - warmup, 1)
    progress = min(epoch - warmup, span) / span
    cos = 0.5 * (1.0 + math.cos(math.pi * progress))
    return config.lr * (config.lr_final_factor + (1.0 - config.lr_final_factor) * cos)


def selection_certificate(model: LSTMModel, config: TrainingConfig) -> tuple[bool, str]:
    r"""Whether a checkpoint may be selected: the library's
    :func:`~ltv_lstm_mpc.certify` with the paper's settings
    (``u_max`` and ``Q_s`` of the config) succeeds (Assumption 2, Lemma 2, Theorem 2 and
    the tightening of eq. constraint_tightening_parameters) and, with
    ``selection_rho_s_max``, :math:`\rho_s` is at most that. :func:`train` also needs a
    non-empty admissible set-point interval of Assumption 5 at the paper's
    :math:`d_{max} = 0.1` (:func:`check_checkpoint`; the default :math:`d_{max}` of the
    controller), unless ``allow_empty_interval``.

    Returns
    -------
    eligible : bool
    reason : str
        Empty when eligible, else why not.
    """
    from ltv_lstm_mpc.certificates.certify import CertificationSettings, certify

    try:
        certification = certify(model, CertificationSettings(u_max=config.u_max, Q_s=config.Q_s))
    except LtvMpcError as error:
        return False, f"certify failed: {error}"
    rho_s = certification.lyapunov.rho_s
    if config.selection_rho_s_max is not None and rho_s > config.selection_rho_s_max:
        return False, f"rho_s = {rho_s:.4f} > {config.selection_rho_s_max}"
    return True, ""


@dataclass(frozen=True)
class CheckpointCheck:
    r"""What model selection needs to know about one checkpoint (:func:`check_checkpoint`).

    Attributes
    ----------
    certified : bool
        :func:`~ltv_lstm_mpc.certify` with the paper's settings succeeded (Assumption 2,
        Lemma 2, Theorem 2, tightening).
    reason : str
        Why certify failed (empty when it succeeded).
    rho_s : float
        :math:`\rho_s` of Lemma 2 (nan when certify failed).
    interval_phi : (list, list) or None
        The admissible set-point interval of Assumption 5 at the paper's
        :math:`d_{max} = 0.1` in physical units, (low, high) per output; None when certify
        failed or the interval is empty.
    interval_margin : float
        :math:`2 d_{max} + a_N \tilde e_o + b_N` (normalized, largest over the outputs): the
        interval is non-empty where it is below half the normalized output constraint's
        width (``constraint_half_width``).
    constraint_half_width : float
        Half the width of the normalized output constraint (smallest over the outputs).
    """

    certified: bool
    reason: str
    rho_s: float
    interval_phi: tuple[list[float], list[float]] | None
    interval_margin: float = math.nan
    constraint_half_width: float = math.nan

    @property
    def has_interval(self) -> bool:
        """Certified with a non-empty admissible set-point interval (Assumption 5)."""
        return self.certified and self.interval_phi is not None


def check_checkpoint(model: LSTMModel, config: TrainingConfig) -> CheckpointCheck:
    r"""Certify a checkpoint with the paper's settings (``u_max``, ``Q_s`` of the config,
    :math:`d_{max} = 0.1`) and read its :math:`\rho_s` and admissible set-point interval
    (Assumption 5), for model selection in :func:`train`."""
    from ltv_lstm_mpc.certificates.certify import CertificationSettings, certify

    try:
        certification = certify(model, CertificationSettings(u_max=config.u_max, Q_s=config.Q_s))
    except LtvMpcError as error:
        return CheckpointCheck(False, f"certify failed: {error}", math.nan, None)
    tightening = certification.tightening
    margin = 2.0 * tightening.d_max + tightening.a[tightening.N] * tightening.e_inf
    margin = margin + tightening.b[tightening.N]
    half_width = 0.5 * (np.asarray(tightening.y_max) - np.asarray(tightening.y_min))
    low, high = certification.y0_interval
    phi = certification.y0_interval_phi
    interval: tuple[list[float], list[float]] | None = None
    if np.all(low < high):
        bounds = phi if phi is not None else (low, high)
        interval = (np.asarray(bounds[0]).tolist(), np.asarray(bounds[1]).tolist())
    return CheckpointCheck(
        True,
        "",
        float(certification.lyapunov.rho_s),
        interval,
        float(np.max(margin)),
        float(np.min(half_width)),
    )


#: The selection pools of :func:`train`, in order of preference.
SELECTION_POOLS = ("bound", "interval", "empty_interval")


def _selection_tracker() -> dict[str, Any]:
    """What :func:`train` records about the checkpoints for its message when no model
    qualifies (plain values: it travels in the torch checkpoint)."""
    return {
        "delta_iss": 0,
        "first_delta_iss_epoch": None,
        "min_rho_s": math.inf,
        "min_rho_s_epoch": None,
        "checked": 0,
        "certify_failed": 0,
        "certify_reason": "",
        "interval_empty": 0,
        "min_margin_excess": math.inf,
        "min_margin_excess_epoch": None,
        "within_bound": 0,
    }


def _pick(pools: dict[str, Any], config: TrainingConfig) -> tuple[dict[str, Any] | None, str]:
    """The checkpoint to export and the pool it comes from (see :func:`train`)."""
    if pools.get("bound") is not None:
        return pools["bound"], "bound"
    if (config.selection_fallback or config.selection_rho_s_max is None) and pools.get(
        "interval"
    ) is not None:
        return pools["interval"], "interval"
    if config.allow_empty_interval and pools.get("empty_interval") is not None:
        return pools["empty_interval"], "empty_interval"
    return None, ""


def _no_model_message(
    config: TrainingConfig, epoch: int, tracker: dict[str, Any], last: dict[str, float]
) -> str:
    """Why no checkpoint qualified, naming the first selection constraint that failed."""
    tail = " The checkpoint in the output folder allows resuming."
    if not tracker["delta_iss"]:
        return (
            f"no delta-ISS certified weights after {epoch} epochs (the planned "
            f"{config.epochs} plus at most {config.max_extra_epochs} extra): Assumption 2 "
            f"never held, last r1 = {last['r1']:.4g}, r2 = {last['r2']:.4g} (rho(A_delta) = "
            f"{last.get('rho_A_delta', math.nan):.4g}), both r1 and r2 must be < 0. Train "
            "longer (--epochs; with --preset fidelity the learning rate has decayed to "
            "lr_final_factor x lr at the planned epochs, so extra epochs move slowly), "
            "increase lambda1, or raise the learning rate." + tail
        )
    counted = (
        f"{tracker['delta_iss']} evaluations of the {epoch} epochs were delta-ISS (first at "
        f"epoch {tracker['first_delta_iss_epoch']})"
    )
    bound = config.selection_rho_s_max
    if tracker["checked"] and tracker["certify_failed"] == tracker["checked"]:
        return (
            f"{counted}, but certify() with the paper's settings failed on every one checked "
            f"({tracker['checked']}); the last: {tracker['certify_reason']}." + tail
        )
    if bound is not None and not tracker["within_bound"] and not config.selection_fallback:
        return (
            f"{counted}, but none met the selection bound rho_s <= {bound}: the smallest "
            f"rho_s was {tracker['min_rho_s']:.4f} (epoch {tracker['min_rho_s_epoch']}). "
            f"Raise --selection-rho-s-max above {tracker['min_rho_s']:.3f}, or shrink rho_s "
            "with a larger delta_iss_margin or lambda2; selection_fallback = True selects "
            "by a non-empty set-point interval instead." + tail
        )
    excess = tracker["min_margin_excess"]
    return (
        f"{counted} and {tracker['checked'] - tracker['certify_failed']} passed certify(), "
        "but the admissible set-point interval of Assumption 5 (at the paper's d_max = 0.1) "
        f"is empty for every one: 2 d_max + a_N e_inf + b_N exceeds half the normalized "
        f"output constraint by at least {excess:.4g} (epoch "
        f"{tracker['min_margin_excess_epoch']}); their smallest rho_s was "
        f"{tracker['min_rho_s']:.4f}, and the tightening grows as rho_s -> 1. Shrink rho_s "
        "(a larger delta_iss_margin or lambda2, more epochs), give the model a wider "
        "output constraint relative to the data's output range, or pass "
        "--allow-empty-interval (TrainingConfig.allow_empty_interval) to write the model "
        "anyway and run it with a smaller d_max." + tail
    )


def _estimated_pole(y: FloatArray, u: FloatArray) -> float:
    """Pole of a first-order ARX model y[k+1] = a y[k] + b u[k] + c fitted by least
    squares to one output (normalized data, shape (S, T) and (S, T, m))."""
    target = y[:, 1:].ravel()
    regressors = np.column_stack(
        [y[:, :-1].ravel(), u[:, :-1].reshape(target.size, -1), np.ones(target.size)]
    )
    theta, *_ = np.linalg.lstsq(regressors, target, rcond=None)
    return float(theta[0])


def preflight(dataset: IdentificationDataset, config: TrainingConfig) -> list[str]:
    r"""Check the data against what a certified model needs, before training.

    * The output constraint (the data's ``y_phi_constraint``) against the data's output
      range: the normalization maps the training outputs onto [-1, 1]; the admissible
      set-point interval of Assumption 5 is empty for every model where the normalized
      constraint is no wider than :math:`4 d_{max}` (0.4 at the paper's
      :math:`d_{max} = 0.1`), or where it does not overlap the data.
    * The sampling time: the time constant of a first-order ARX fit of each output, in
      samples. A model reproduces it with a pole near :math:`e^{-1/\tau}`, and
      :math:`\rho_s \ge \rho(A_\delta) \ge` the model's slowest pole, so slow dynamics in
      samples (a short ``Ts``) push :math:`\rho_s` towards 1, where the tightening of
      Assumption 5 grows without bound.

    Parameters
    ----------
    dataset : IdentificationDataset
    config : TrainingConfig

    Returns
    -------
    list of str
        Findings, one line each (facts and advice).

    Raises
    ------
    TrainingError
        The constraint leaves no admissible set-point for any model (unless
        ``config.allow_empty_interval``); the message names the numbers and the fix.
    """
    normalization = dataset.normalization()
    u, y = dataset.channels("train")
    low, high = _data_constraint(dataset)
    p = normalization.y_phi_min.shape[0]
    low_v = np.broadcast_to(np.asarray(low, dtype=np.float64), (p,))
    high_v = np.broadcast_to(np.asarray(high, dtype=np.float64), (p,))
    low_n, high_n = normalization.normalize_y(low_v), normalization.normalize_y(high_v)
    unit = str(dataset.metadata.get("units", {}).get("y_phi", "output units"))
    labels = unit.split(", ") if len(unit.split(", ")) == p else [unit] * p
    Ts = dataset.metadata.get("Ts")
    lines: list[str] = []
    u_n, y_n = normalization.normalize_u(u), normalization.normalize_y(y)
    for j in range(p):
        y_lo, y_hi = float(normalization.y_phi_min[j]), float(normalization.y_phi_max[j])
        width = float(high_n[j] - low_n[j])
        overlap = min(high_v[j], y_hi) - max(low_v[j], y_lo)
        lines.append(
            f"output {j} ({labels[j]}): training data span [{y_lo:.4g}, {y_hi:.4g}], output "
            f"constraint [{low_v[j]:.4g}, {high_v[j]:.4g}] (normalized "
            f"[{low_n[j]:.3f}, {high_n[j]:.3f}], width {width:.3f})"
        )
        problem = ""
        if overlap <= 0:
            problem = (
                f"the output constraint [{low_v[j]:.4g}, {high_v[j]:.4g}] ({labels[j]}) does not "
                f"overlap the data's outputs [{y_lo:.4g}, {y_hi:.4g}]: check the plant's "
                "y_phi_constraint and its units, or generate data that reach the constraint"
            )
        elif width <= 4.0 * 0.1:
            problem = (
                f"the output constraint [{low_v[j]:.4g}, {high_v[j]:.4g}] ({labels[j]}) is "
                f"{width:.3f} wide in normalized units (the data's outputs "
                f"[{y_lo:.4g}, {y_hi:.4g}] map to [-1, 1]), not more than 4 d_max = 0.4: "
                "the admissible set-point interval of Assumption 5 is empty for any model. "
                "Generate data over an output range closer to the constraint (a narrower "
                "input range), or widen the constraint"
            )
        if problem and not config.allow_empty_interval:
            raise TrainingError(
                f"before training: {problem} (or pass --allow-empty-interval to train anyway)"
            )
        if problem:
            lines.append("warning: " + problem)
        pole = _estimated_pole(y_n[..., j], u_n)
        if 0.0 < pole < 1.0:
            tau = -1.0 / math.log(pole)
            seconds = "" if Ts is None else f" = {tau * float(Ts):.3g} s at Ts = {float(Ts):g} s"
            lines.append(
                f"output {j}: first-order time constant {tau:.3g} samples{seconds} (pole "
                f"{pole:.3f} per sample; rho_s is at least the model's slowest pole)"
            )
            if tau > 100.0:
                lines.append(
                    f"warning: output {j} settles over hundreds of samples: rho_s will be "
                    "close to 1 and the admissible set-point interval small or empty; "
                    "sample slower (a longer Ts, about 5-30 samples per time constant)"
                )
            elif tau < 1.0:
                lines.append(
                    f"warning: output {j} settles within a sample: Ts is long for its "
                    "dynamics; sample faster (about 5-30 samples per time constant)"
                )
        else:
            lines.append(
                f"output {j}: no first-order time constant fits the data (pole {pole:.3f}); "
                "check that the outputs respond to the inputs"
            )
    return lines


def _build_network(config: TrainingConfig, m: int = 1, p: int = 1) -> tuple[Any, Any]:
    torch = _import_torch()
    dtype = torch.float64 if config.dtype == "float64" else torch.float32
    torch.manual_seed(config.seed)
    lstm = torch.nn.LSTM(input_size=m, hidden_size=config.n, batch_first=True).to(dtype)
    linear = torch.nn.Linear(config.n, p).to(dtype)
    if config.forget_bias_init is not None:
        n = config.n
        with torch.no_grad():
            lstm.bias_ih_l0[n : 2 * n] = config.forget_bias_init
            lstm.bias_hh_l0[n : 2 * n] = 0.0
    return lstm, linear


def _state_dict(lstm: Any, linear: Any) -> dict[str, Any]:
    out = {f"lstm.{k}": v.detach().clone() for k, v in lstm.state_dict().items()}
    out.update({f"linear.{k}": v.detach().clone() for k, v in linear.state_dict().items()})
    return out


def _export(
    state: dict[str, Any],
    normalization: Normalization,
    y_phi_constraint: tuple[Any, Any],
    Ts: float | None = None,
) -> LSTMModel:
    arrays = {k: v.detach().cpu().double().numpy() for k, v in state.items()}
    # The output constraint (the data's, see _data_constraint) and the sampling time travel
    # with the model.
    p = normalization.y_phi_min.shape[0]
    low, high = (np.broadcast_to(np.asarray(v, dtype=np.float64), (p,)) for v in y_phi_constraint)
    return LSTMModel.from_torch_state_dict(
        arrays, normalization=normalization, y_phi_constraint=(low, high), Ts=Ts
    )


def _data_constraint(dataset: IdentificationDataset) -> tuple[Any, Any]:
    """The output constraint stated by the data (``y_phi_constraint``: one (low, high) per
    output), else the one of the registered plant that made the data (data files written
    before the constraint was stored: the pH benchmark's)."""
    stated = dataset.metadata.get("y_phi_constraint")
    if stated is None:
        from ltv_lstm_mpc.plants.registry import plant_name_of, resolve_plant

        plant = dataset.metadata.get("plant", "PHNeutralizationPlant")
        name = plant_name_of(plant)
        registered = None if name is None else resolve_plant(name).y_phi_constraint
        if registered is None:
            raise InvalidValueError(
                f"the data of {plant} state no output constraint (metadata y_phi_constraint) "
                "and the model needs one (the set Y of eq. (optimization)): give the plant a "
                "y_phi_constraint = (low, high) attribute and generate the data again, or set "
                "dataset.metadata['y_phi_constraint']"
            )
        stated = registered
    pairs = np.asarray(stated, dtype=np.float64).reshape(-1, 2)
    return pairs[:, 0], pairs[:, 1]


def _initial_state(
    lstm: Any, u0: float | FloatArray, batch: int, config: TrainingConfig
) -> tuple[Any, Any]:
    """Approximate equilibrium (h, c) for the constant normalized input u0 (a number or one
    value per input), expanded to a batch."""
    torch = _import_torch()
    dtype = lstm.weight_hh_l0.dtype
    n = config.n
    u0_row = torch.as_tensor(np.atleast_1d(np.asarray(u0, dtype=np.float64)), dtype=dtype)
    h = torch.zeros(1, 1, n, dtype=dtype)
    c = torch.zeros(1, 1, n, dtype=dtype)
    if config.equilibrium_steps > 0:
        with torch.no_grad():
            u = u0_row.expand(1, config.equilibrium_steps, u0_row.shape[0])
            _, (h, c) = lstm(u, (h, c))
    if config.equilibrium_grad_steps > 0:
        u = u0_row.expand(1, config.equilibrium_grad_steps, u0_row.shape[0])
        _, (h, c) = lstm(u, (h.detach(), c.detach()))
    return h.expand(1, batch, n).contiguous(), c.expand(1, batch, n).contiguous()


def _predict(lstm: Any, linear: Any, u: Any, state: tuple[Any, Any]) -> tuple[Any, tuple[Any, Any]]:
    """Outputs aligned with the data (y_k from h_k) for inputs u (B, L, m) from state (h, c)."""
    torch = _import_torch()
    out, new_state = lstm(u, state)
    h_seq = torch.cat([state[0].transpose(0, 1), out[:, :-1]], dim=1)
    return linear(h_seq), new_state


def _numpy_fit(model: LSTMModel, dataset: IdentificationDataset, split: str) -> float:
    """FIT of one split with the exported model (:func:`evaluate_model`'s definition)."""
    return float(evaluate_model(model, dataset, (split,))[split]["fit"])


def _library_version() -> str:
    try:
        from importlib.metadata import version

        return version("ltv_lstm_mpc")
    except Exception:  # pragma: no cover - not installed
        return "unknown"


# ------------------------------------------------------------------- guarantees
def guarantee_numbers(
    model: LSTMModel, dataset: IdentificationDataset, config: TrainingConfig
) -> dict[str, Any]:
    r"""What the robust guarantees need from the model, for the training report.

    * ``d_max_estimate``: :func:`~ltv_lstm_mpc.estimate_d_max` of the
      model on the validation split (training split when there is none), 10 % margin;
      single-input single-output models only (else None).
    * ``setpoint_interval_phi``: the admissible set-point interval of Assumption 5
      (physical units, from :func:`~ltv_lstm_mpc.certify` with the
      paper's settings) for the paper's :math:`d_{max} = 0.1` (``"paper_d_max"``) and for
      the estimated one (``"estimated_d_max"``); None where certify fails or the interval
      is empty, with the reason under ``setpoint_interval_errors``.

    Parameters
    ----------
    model : LSTMModel
        The exported, certified model.
    dataset : IdentificationDataset
        Its identification data.
    config : TrainingConfig
        ``u_max`` and ``Q_s`` of the certificates.

    Returns
    -------
    dict
        Keys ``d_max_estimate``, ``setpoint_interval_phi``, ``setpoint_interval_errors``.
    """
    from ltv_lstm_mpc.certificates.certify import CertificationSettings, certify
    from ltv_lstm_mpc.training.mismatch import estimate_d_max

    estimate: dict[str, Any] | None = None
    d_max_values: dict[str, float] = {"paper_d_max": CertificationSettings().d_max}
    if model.m == 1 and model.p == 1:
        split = "val" if dataset.u_phi["val"].shape[0] > 0 else "train"
        found = estimate_d_max(model, dataset, splits=(split,))
        estimate = {
            "d_max": found.d_max,
            "mismatch": found.mismatch,
            "mismatch_phi": found.mismatch_phi,
            "margin": found.margin,
            "splits": list(found.splits),
            "worst": list(found.worst),
        }
        d_max_values["estimated_d_max"] = found.d_max
    intervals: dict[str, Any] = {}
    errors: dict[str, str] = {}
    for key, d_max in d_max_values.items():
        try:
            settings = CertificationSettings(u_max=config.u_max, Q_s=config.Q_s, d_max=d_max)
            certification = certify(model, settings)
        except LtvMpcError as error:
            intervals[key], errors[key] = None, str(error)
            continue
        low, high = certification.y0_interval
        phi = certification.y0_interval_phi
        if not np.all(low < high) or phi is None:
            intervals[key], errors[key] = None, "empty set-point interval (Assumption 5)"
            continue
        intervals[key] = {"d_max": d_max, "low": phi[0].tolist(), "high": phi[1].tolist()}
    return {
        "d_max_estimate": estimate,
        "setpoint_interval_phi": intervals,
        "setpoint_interval_errors": errors,
    }


# --------------------------------------------------------------------------- plots
HISTORY_COLUMNS = (
    "epoch",
    "loss",
    "mse",
    "r1",
    "r2",
    "rho_A_delta",
    "rho_s",
    "fit_val",
    "certified",
    "margin_term",
    "lr",
)


def write_history_csv(history: list[dict[str, float]], path: str | Path) -> Path:
    """The per-evaluation records of :func:`train` as CSV (columns :data:`HISTORY_COLUMNS`;
    a record without a column, e.g. from an older checkpoint, leaves it empty)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [",".join(HISTORY_COLUMNS)]
    for record in history:
        cells = (repr(float(record[c])) if c in record else "" for c in HISTORY_COLUMNS)
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def plot_training_curves(
    history: list[dict[str, float]], path: str | Path, *, best_epoch: int | None = None
) -> Path:
    r"""PNG of the validation FIT and of :math:`\rho(A_\delta)` (Assumption 2) and
    :math:`\rho_s` (Lemma 2) against the epoch, the selected epoch marked (Agg backend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = np.array([r["epoch"] for r in history])
    fit = np.array([r["fit_val"] for r in history])
    rho = np.array([r["rho_A_delta"] for r in history])
    rho_s = np.array([r.get("rho_s", np.nan) for r in history])
    fig, (ax_f, ax_r) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    ax_f.plot(epochs, fit, color="C3", lw=1.0)
    ax_f.set_ylabel("validation FIT (%)")
    finite = fit[np.isfinite(fit)]
    if finite.size:
        top = float(np.max(finite))
        ax_f.set_ylim(max(float(np.min(finite)), top - 15.0), top + 1.0)
    ax_r.plot(epochs, rho, color="C0", lw=1.0, label=r"$\rho(A_\delta)$")
    ax_r.plot(epochs, rho_s, color="C2", lw=1.0, label=r"$\rho_s$ ($Q_s$ = 1000 I)")
    ax_r.axhline(1.0, color="k", lw=0.8, ls=":")
    low = np.nanmin(np.concatenate([rho, rho_s])) if np.any(np.isfinite(rho)) else 0.0
    ax_r.set_ylim(max(0.0, float(low) - 0.02), 1.05)  # the first epochs may start far above 1
    ax_r.set_ylabel("spectral radius")
    ax_r.set_xlabel("epoch")
    ax_r.legend(loc="upper right")
    if best_epoch is not None:
        for ax in (ax_f, ax_r):
            ax.axvline(best_epoch, color="k", lw=0.8, ls="--")
        ax_f.set_title(f"selected epoch {best_epoch}")
    return _save_figure(fig, path)


def _save_figure(fig: Any, path: str | Path) -> Path:
    """Lay out ``fig``, write it as PNG to ``path`` (folders created) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def plot_prediction(
    model: LSTMModel,
    dataset: IdentificationDataset,
    path: str | Path,
    split: str = "test",
) -> Path:
    """PNG of the model's open-loop prediction against the plant on one split (Agg backend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ph_data = dataset.metadata.get("plant", "PHNeutralizationPlant") == "PHNeutralizationPlant"
    if dataset.inputs > 1 or dataset.outputs > 1 or not ph_data:
        # any process but the pH one: generic channel labels, its own initial input
        return _plot_prediction_channels(model, dataset, Path(path), split)
    u, y = dataset.split(split)
    pred = simulate_sequences(model, u, float(initial_input(dataset.metadata)[0]))
    Ts = float(dataset.metadata.get("Ts", 10.0))
    rows = u.shape[0]
    fig, axes = plt.subplots(2 * rows, 1, figsize=(10, 3.2 * rows + 1), sharex=True, squeeze=False)
    t = np.arange(u.shape[1]) * Ts / 60.0
    for row in range(rows):
        ax_y, ax_u = axes[2 * row, 0], axes[2 * row + 1, 0]
        ax_y.plot(t, y[row], label="plant", color="k", lw=1.2)
        ax_y.plot(t, pred[row], label="LSTM", color="tab:blue", lw=1.0, ls="--")
        ax_y.set_ylabel(str(dataset.metadata.get("units", {}).get("y_phi", "y")))
        ax_y.set_title(f"{split} sequence {row}: FIT {fit_index(y[row], pred[row]):.1f} %")
        ax_y.legend(loc="upper right")
        ax_u.step(t, u[row], where="post", color="tab:orange", lw=1.0)
        ax_u.set_ylabel("q3 (mL/s)")
    axes[-1, 0].set_xlabel("time (min)")
    fig.suptitle(f"Open-loop prediction on the {split} set: FIT {fit_index(y, pred):.2f} %")
    return _save_figure(fig, path)


def _plot_prediction_channels(
    model: LSTMModel, dataset: IdentificationDataset, path: Path, split: str
) -> Path:
    """The multi-channel version of :func:`plot_prediction`: per sequence, every output
    (plant vs LSTM) and the inputs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    u, y = dataset.channels(split)
    pred = simulate_sequences(model, u, initial_input(dataset.metadata))
    Ts = float(dataset.metadata.get("Ts", 10.0))
    rows, p = u.shape[0], y.shape[2]
    fig, axes = plt.subplots(rows * (p + 1), 1, figsize=(10, 2.2 * rows * (p + 1) + 1),
                             sharex=True, squeeze=False)  # fmt: skip
    t = np.arange(u.shape[1]) * Ts / 60.0
    for row in range(rows):
        for j in range(p):
            ax = axes[row * (p + 1) + j, 0]
            ax.plot(t, y[row, :, j], label="plant", color="k", lw=1.2)
            ax.plot(t, pred[row, :, j], label="LSTM", color="tab:blue", lw=1.0, ls="--")
            ax.set_ylabel(f"y_{j}")
            ax.set_title(
                f"{split} sequence {row}, output {j}: FIT "
                f"{fit_index(y[row, :, j], pred[row, :, j]):.1f} %"
            )
            ax.legend(loc="upper right")
        ax_u = axes[row * (p + 1) + p, 0]
        for j in range(u.shape[2]):
            ax_u.step(t, u[row, :, j], where="post", lw=1.0, label=f"u_{j}")
        ax_u.legend(loc="upper right")
    axes[-1, 0].set_xlabel("time (min)")
    fits = ", ".join(f"{fit_index(y[..., j], pred[..., j]):.2f} %" for j in range(p))
    fig.suptitle(f"Open-loop prediction on the {split} set: FIT per output {fits}")
    return _save_figure(fig, path)


# --------------------------------------------------------------------------- train
def train(
    dataset: IdentificationDataset,
    config: TrainingConfig | None = None,
    out_dir: str | Path = "training_output",
    *,
    progress: bool = True,
    resume: bool = True,
    name: str | None = None,
    callback: Callable[[dict[str, float]], None] | None = None,
) -> TrainingResult:
    """Train a delta-ISS LSTM on ``dataset`` and export model, report and plot to ``out_dir``.

    Parameters
    ----------
    dataset : IdentificationDataset
        Identification data (normalization from its training split).
    config : TrainingConfig, optional
        Defaults reproduce the paper.
    out_dir : path
        Output folder: ``<name>.npz`` (core model format), ``<name>_report.json``,
        ``<name>_test_prediction.png`` and ``checkpoint.pt``.
    progress : bool
        Show a tqdm progress bar (loss, FIT(val), r1, r2).
    resume : bool
        Continue from ``out_dir/checkpoint.pt`` if it exists and its config matches.
    name : str, optional
        File stem; default ``<stem>_n<n>`` with the data's ``model_stem`` (pH data:
        ``ph_lstm``).
    callback : callable, optional
        Called with each evaluation record.

    Raises
    ------
    TrainingError
        No certified delta-ISS weights after ``epochs + max_extra_epochs`` epochs.
    ImportError
        torch is not installed (the message says how to install it).
    """
    torch = _import_torch()
    from tqdm.auto import tqdm

    config = config if config is not None else TrainingConfig()
    findings = preflight(dataset, config)  # raises before training where no model can do
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = str(dataset.metadata.get("model_stem", "ph_lstm"))
    name = name if name is not None else f"{stem}_n{config.n}"
    torch.set_num_threads(config.threads)
    dtype = torch.float64 if config.dtype == "float64" else torch.float32

    normalization = dataset.normalization()
    T = dataset.u_phi["train"].shape[1]
    if config.washout >= T:
        raise InvalidValueError(
            f"washout {config.washout} must be shorter than the sequences ({T})"
        )

    def tensor(a: FloatArray) -> Any:
        return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)

    u_tr3, y_tr3 = dataset.channels("train")
    u_tr = tensor(normalization.normalize_u(u_tr3))
    y_tr = tensor(normalization.normalize_y(y_tr3))
    has_val = dataset.u_phi["val"].shape[0] > 0
    u0_norm = normalization.normalize_u(initial_input(dataset.metadata))
    u0: float | FloatArray = float(u0_norm[0]) if u0_norm.shape == (1,) else u0_norm
    constraint = _data_constraint(dataset)
    Ts = dataset.metadata.get("Ts")
    Ts_value = None if Ts is None else float(Ts)

    def export(state: dict[str, Any]) -> LSTMModel:
        return _export(state, normalization, constraint, Ts_value)

    lstm, linear = _build_network(config, dataset.inputs, dataset.outputs)
    params = list(lstm.parameters()) + list(linear.parameters())
    optimizer = torch.optim.Adam(params, lr=config.lr)
    rng = np.random.default_rng(config.seed)

    S = u_tr.shape[0]
    batch = config.batch_size if 0 < config.batch_size < S else S
    chunk = config.truncation if 0 < config.truncation < T else T

    epoch = 0
    certified_now = False
    margin_on = True
    history: list[dict[str, float]] = []
    # The best validation FIT per selection pool (SELECTION_POOLS): "bound" within
    # selection_rho_s_max with a non-empty interval, "interval" any rho_s with a non-empty
    # interval, "empty_interval" within the bound whatever the interval.
    pools: dict[str, Any] = dict.fromkeys(SELECTION_POOLS)
    tracker = _selection_tracker()
    elapsed_before = 0.0
    ckpt_path = out / CHECKPOINT_NAME
    if resume and ckpt_path.exists():
        ckpt = torch.load(ckpt_path, weights_only=True)
        if ckpt.get("config") != config.to_dict():
            raise TrainingError(
                f"{ckpt_path} was written with a different configuration; remove it or use "
                "resume=False (--no-resume) to start over"
            )
        lstm.load_state_dict(ckpt["lstm"])
        linear.load_state_dict(ckpt["linear"])
        optimizer.load_state_dict(ckpt["optimizer"])
        rng.bit_generator.state = ckpt["rng"]
        epoch = int(ckpt["epoch"])
        history = list(ckpt["history"])
        pools = dict(ckpt["best"])
        tracker = dict(ckpt["selection"])
        elapsed_before = float(ckpt["elapsed"])
        resumed_cert = delta_iss_certificate(export(_state_dict(lstm, linear)), config.u_max)
        certified_now = resumed_cert.is_delta_iss
        margin_on = margin_term_active(resumed_cert.rho_A_delta, config)

    def save_checkpoint() -> None:
        tmp = ckpt_path.with_suffix(".tmp")
        torch.save(
            {
                "config": config.to_dict(),
                "lstm": lstm.state_dict(),
                "linear": linear.state_dict(),
                "optimizer": optimizer.state_dict(),
                "rng": rng.bit_generator.state,
                "epoch": epoch,
                "history": history,
                "best": pools,
                "selection": tracker,
                "elapsed": elapsed_before + (time.perf_counter() - start),
            },
            tmp,
        )
        tmp.replace(ckpt_path)

    max_epochs = config.epochs + config.max_extra_epochs
    start = time.perf_counter()
    bar = tqdm(total=config.epochs, initial=min(epoch, config.epochs), disable=not progress,
               desc="train", unit="epoch", dynamic_ncols=True)  # fmt: skip
    try:
        while epoch < max_epochs:
            if epoch >= config.epochs and certified_now and _pick(pools, config)[0] is not None:
                break
            for group in optimizer.param_groups:
                group["lr"] = learning_rate(epoch, config)
            escalation = escalation_factor(epoch, config)
            order = rng.permutation(S)
            loss_sum, mse_sum, steps = 0.0, 0.0, 0
            for b0 in range(0, S, batch):
                idx = torch.as_tensor(order[b0 : b0 + batch])
                ub, yb = u_tr[idx], y_tr[idx]
                state = _initial_state(lstm, u0, ub.shape[0], config)
                for s0 in range(0, T, chunk):
                    s1 = min(s0 + chunk, T)
                    pred, new_state = _predict(lstm, linear, ub[:, s0:s1], state)
                    lo = max(config.washout - s0, 0)
                    blocks = _gate_blocks(lstm)
                    r1, r2 = torch_residuals(blocks, config.u_max)
                    penalty = _delta_iss_penalty(r1, r2, config, margin_on, escalation)
                    if lo < s1 - s0:
                        mse = torch.mean((pred[:, lo:] - yb[:, s0 + lo : s1]) ** 2)
                    else:
                        mse = torch.zeros((), dtype=dtype)
                    loss = mse + penalty
                    optimizer.zero_grad(set_to_none=True)
                    loss.backward()
                    if config.grad_clip_norm > 0:
                        torch.nn.utils.clip_grad_norm_(params, config.grad_clip_norm)
                    optimizer.step()
                    state = (new_state[0].detach(), new_state[1].detach())
                    loss_sum += float(loss.detach())
                    mse_sum += float(mse.detach())
                    steps += 1
            epoch += 1
            if epoch <= config.epochs:
                bar.update(1)
            model_np = export(_state_dict(lstm, linear))
            cert = delta_iss_certificate(model_np, config.u_max)
            certified_now = cert.is_delta_iss
            margin_was_on = margin_on
            margin_on = margin_term_active(cert.rho_A_delta, config)
            if epoch % config.eval_every == 0 or epoch >= config.epochs:
                # Validation FIT of the exported float64 model from its exact equilibrium
                # (the report's definition), not the training surrogate.
                fit_val = _numpy_fit(model_np, dataset, "val" if has_val else "train")
                record: dict[str, float] = {
                    "epoch": float(epoch),
                    "loss": loss_sum / steps,
                    "mse": mse_sum / steps,
                    "r1": cert.r1,
                    "r2": cert.r2,
                    "rho_A_delta": cert.rho_A_delta,
                    "fit_val": fit_val,
                    "certified": float(certified_now),
                    "margin_term": float(margin_was_on),
                    "lr": float(optimizer.param_groups[0]["lr"]),
                }
                if certified_now:  # rho_s (Lemma 2) exists for delta-ISS weights only
                    lyapunov = incremental_lyapunov_certificate(model_np, cert, Q_s=config.Q_s)
                    record["rho_s"] = lyapunov.rho_s
                history.append(record)
                if callback is not None:
                    callback(record)
                if certified_now:
                    _select(model_np, lstm, linear, record, config, pools, tracker)
                best = _pick(pools, config)[0]
                bar.set_postfix(
                    loss=f"{record['loss']:.2e}",
                    fit_val=f"{fit_val:.2f}",
                    r1=f"{cert.r1:.3f}",
                    r2=f"{cert.r2:.3f}",
                    best=f"{best['fit_val']:.2f}" if best else "-",
                )
            if config.checkpoint_every and epoch % config.checkpoint_every == 0:
                save_checkpoint()
    finally:
        bar.close()
    if config.checkpoint_every:
        save_checkpoint()
    wall_time = elapsed_before + (time.perf_counter() - start)
    best, pool = _pick(pools, config)
    if best is None:
        last = history[-1] if history else {"r1": math.nan, "r2": math.nan}
        raise TrainingError(_no_model_message(config, epoch, tracker, last))
    # If the last weights are not certified (extra epochs exhausted) the best certified ones
    # seen earlier are still exported; the report records it ("final_weights_certified").
    model = export(best["state"])
    outcome = {
        "pool": pool,
        "rho_s_bound_met": pool == "bound" or config.selection_rho_s_max is None,
        "interval_empty": pool == "empty_interval" and best.get("interval") is None,
        "smallest_rho_s_seen": None if math.isinf(tracker["min_rho_s"]) else tracker["min_rho_s"],
        "preflight": findings,
    }
    return _finish(
        model, dataset, config, out, name, history, best, epoch, wall_time, certified_now,
        outcome,
    )  # fmt: skip


def _select(
    model: LSTMModel,
    lstm: Any,
    linear: Any,
    record: dict[str, float],
    config: TrainingConfig,
    pools: dict[str, Any],
    tracker: dict[str, Any],
) -> None:
    """Offer a delta-ISS checkpoint to the selection pools of :func:`train` (certify()
    runs only when its validation FIT beats a pool it could enter)."""
    epoch, fit_val, rho_s = int(record["epoch"]), record["fit_val"], record["rho_s"]
    tracker["delta_iss"] += 1
    if tracker["first_delta_iss_epoch"] is None:
        tracker["first_delta_iss_epoch"] = epoch
    if rho_s < tracker["min_rho_s"]:
        tracker["min_rho_s"], tracker["min_rho_s_epoch"] = rho_s, epoch
    within = config.selection_rho_s_max is None or rho_s <= config.selection_rho_s_max
    tracker["within_bound"] += int(within)

    def beats(pool: str) -> bool:
        return pools[pool] is None or fit_val > pools[pool]["fit_val"]

    wanted = (
        (within and beats("bound"))
        or beats("interval")
        or (within and config.allow_empty_interval and beats("empty_interval"))
    )
    if not wanted:
        return
    check = check_checkpoint(model, config)
    tracker["checked"] += 1
    if not check.certified:
        tracker["certify_failed"] += 1
        tracker["certify_reason"] = check.reason
        return
    if not check.has_interval:
        tracker["interval_empty"] += 1
        excess = check.interval_margin - check.constraint_half_width
        if excess < tracker["min_margin_excess"]:
            tracker["min_margin_excess"], tracker["min_margin_excess_epoch"] = excess, epoch
    entry = {
        "state": _state_dict(lstm, linear),
        "fit_val": fit_val,
        "epoch": epoch,
        "rho_s": check.rho_s,
        "interval": None if check.interval_phi is None else list(check.interval_phi),
    }
    if within and check.has_interval and beats("bound"):
        pools["bound"] = entry
    if check.has_interval and beats("interval"):
        pools["interval"] = entry
    if within and beats("empty_interval"):
        pools["empty_interval"] = entry


def _selection_sentence(config: TrainingConfig, pool: str) -> str:
    """The report's ``selection`` text: the rule the exported checkpoint was chosen by."""
    bound = config.selection_rho_s_max
    rule = (
        "best validation FIT (exported float64 model, exact equilibrium) among the "
        "evaluated checkpoints that pass certify() with the paper's settings"
    )
    if pool == "bound":
        rule += "" if bound is None else f" and have rho_s <= {bound}"
        rule += " and a non-empty admissible set-point interval (Assumption 5, d_max = 0.1)"
    elif pool == "interval":
        rule += (
            f" and a non-empty admissible set-point interval (Assumption 5, d_max = 0.1); "
            f"no checkpoint met rho_s <= {bound}, so that bound was dropped "
            "(selection_fallback)"
        )
    else:
        rule += (
            ("" if bound is None else f" and have rho_s <= {bound}")
            + "; none had a non-empty admissible set-point interval (Assumption 5, "
            "d_max = 0.1): written because allow_empty_interval is set"
        )
    return rule + "; the test split is evaluated once, on the selected model"


def _finish(
    model: LSTMModel,
    dataset: IdentificationDataset,
    config: TrainingConfig,
    out: Path,
    name: str,
    history: list[dict[str, float]],
    best: dict[str, Any],
    epochs_run: int,
    wall_time: float,
    final_certified: bool,
    outcome: dict[str, Any] | None = None,
) -> TrainingResult:
    torch = _import_torch()
    cert = delta_iss_certificate(model, config.u_max, require=True)
    lyap = incremental_lyapunov_certificate(model, cert, Q_s=config.Q_s)
    fits = evaluate_model(model, dataset)
    model_path = model.save(out / f"{name}.npz")
    report: dict[str, Any] = {
        "model_file": model_path.name,
        "fit": {split: value["fit"] for split, value in fits.items()},
        "fit_per_output": {split: value["fit_per_output"] for split, value in fits.items()},
        "fit_per_sequence": {split: value["fit_per_sequence"] for split, value in fits.items()},
        "fit_definition": (
            "100 (1 - ||y_real - y|| / ||y_real - mean(y_real)||) % on the physical outputs "
            f"({dataset.metadata.get('units', {}).get('y_phi', 'output units')}) of all sequences "
            "of the "
            "split concatenated, per output; 'fit' is the smallest per-output FIT; open-loop "
            "simulation with LSTMModel.simulate from the equilibrium of the data's initial input"
        ),
        "r1": cert.r1,
        "r2": cert.r2,
        "rho_A_delta": cert.rho_A_delta,
        "delta_iss": cert.is_delta_iss,
        "rho_s": lyap.rho_s,
        "Q_s": config.Q_s,
        "u_max": config.u_max,
        "epochs_run": epochs_run,
        "final_weights_certified": bool(final_certified),
        "best_epoch": int(best["epoch"]),
        "best_fit_val": float(best["fit_val"]),
        "selection": _selection_sentence(config, (outcome or {}).get("pool", "bound")),
        "selection_outcome": {k: v for k, v in (outcome or {}).items() if k != "preflight"},
        "preflight": (outcome or {}).get("preflight", []),
        "wall_time_s": wall_time,
        "seed": config.seed,
        "config": config.to_dict(),
        "dataset": dict(dataset.metadata),
        "normalization": {
            key: getattr(model.normalization, key).tolist()
            for key in ("u_phi_min", "u_phi_max", "y_phi_min", "y_phi_max")
        },
        "Ts": model.Ts,
        "y_phi_constraint": None
        if model.y_phi_constraint is None
        else [v.tolist() for v in model.y_phi_constraint],
        "initial_state": (
            "LSTM equilibrium for the constant input of the data's initial steady state "
            "(q3_initial or u_phi_initial)"
        ),
        "library_version": _library_version(),
        "torch_version": str(torch.__version__),
        "numpy_version": np.__version__,
        "python_version": platform.python_version(),
        "machine": f"{platform.machine()}, {platform.processor() or 'unknown cpu'}",
    }
    report.update(guarantee_numbers(model, dataset, config))
    report["data_coverage"] = input_coverage(dataset)
    report_path = out / f"{name}_report.json"
    report_path.write_text(json.dumps(report, indent=2, sort_keys=False) + "\n")
    try:
        write_history_csv(history, out / f"{name}_history.csv")
        report_curves: Path | None = plot_training_curves(
            history, out / f"{name}_training_curves.png", best_epoch=int(best["epoch"])
        )
    except Exception:  # pragma: no cover - plotting is best effort
        report_curves = None
    plot_path: Path | None
    try:
        split = next(s for s in ("test", "val", "train") if dataset.u_phi[s].shape[0] > 0)
        plot_path = plot_prediction(model, dataset, out / f"{name}_test_prediction.png", split)
    except Exception:  # pragma: no cover - plotting is best effort
        plot_path = None
    return TrainingResult(
        model=model,
        report=report,
        model_path=model_path,
        report_path=report_path,
        plot_path=plot_path,
        history=history,
        curves_path=report_curves,
    )
