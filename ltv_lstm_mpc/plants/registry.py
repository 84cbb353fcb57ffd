"""The plant registry: every plant name the library understands, with the plant's defaults.

One place turns a plant name into a plant (the "Plant" block of Fig. 1) and the settings
that go with it: the command line (``simulate --plant``, ``generate-data --plant``,
``train --plant``), data generation, training and campaign specs resolve plants only here.

Two kinds of names
------------------
``"ph"``, ``"lstm"``, ``"quadtank"``
    The plants that ship (:func:`registered_plants` lists them); more are added with
    :func:`register_plant`.
``"package.module:Class"``
    A user's own plant class, importable on the Python path (``PYTHONPATH``; a Dask
    campaign worker imports it the same way, so it must be importable there too). The class
    is constructed without arguments and must fill the :class:`~ltv_lstm_mpc.Plant`
    role (``reset``, ``output``, ``step``). Optional class attributes give its defaults:

    =====================================  =====================================================
    attribute                              meaning
    =====================================  =====================================================
    ``Ts``                                 sampling time, s (checked against the model's)
    ``u_phi_min``, ``u_phi_max``           input range (identification data, physical units)
    ``u_phi_initial``                      input of the state ``reset()`` puts the plant in
                                           (the closed loop starts from ``reset()``)
    ``y_phi_constraint``                   output constraint (low, high): stated in generated
                                           data; violations of the plant output are measured
                                           against it
    ``default_model``                      model file used when none is given
    ``default_setpoints``                  set-point per segment (strings, ``"a,b"`` for p > 1)
    ``nominal_disturbance``                disturbance of each segment when none is given
    ``default_neurons``                    LSTM size ``train`` uses for its data
    ``input_labels``, ``output_labels``    names with units, for plots and data files
    =====================================  =====================================================

Example
-------
>>> from ltv_lstm_mpc.plants.registry import resolve_plant
>>> resolve_plant("ph").setpoints
('7.5', '6.8', '8.0')
"""

from __future__ import annotations

import functools
import importlib
import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ltv_lstm_mpc.exceptions import ArgumentTypeError, UnknownPlantError
from ltv_lstm_mpc.plants.ph import PH_REGISTRY_DEFAULTS
from ltv_lstm_mpc.plants.quadtank import QUADTANK_LEVEL_CONSTRAINT
from ltv_lstm_mpc.validation import expect_methods

if TYPE_CHECKING:
    from ltv_lstm_mpc.lstm.model import LSTMModel
    from ltv_lstm_mpc.plants.protocol import Plant

__all__ = [
    "RegisteredPlant",
    "plant_name_of",
    "plant_of_model",
    "register_plant",
    "registered_plants",
    "resolve_plant",
]

#: ``factory(model, **options) -> Plant``; ``model`` is the controller's LSTM model (only
#: the LSTM plant uses it) and ``options`` are the entry's declared options.
PlantFactory = Callable[..., "Plant"]


@dataclass(frozen=True)
class RegisteredPlant:
    """A plant name with its factory and defaults.

    Attributes
    ----------
    name : str
        The name commands and specs use (``"ph"``, or ``"package.module:Class"``).
    title : str
        The plant in a sentence ("pH plant", "quadruple-tank process").
    factory : callable
        ``factory(model, **options)`` returns a new plant (not yet reset).
    description : str
        One line: the process, its inputs, outputs and disturbance with units.
    model : str or None
        Default model (a shipped file name or a path); None: a model must be given.
    setpoints : tuple of str
        Default set-point per segment, physical units (one comma-separated value per output).
    nominal_disturbance : tuple of float or None
        Disturbance of a segment when none is given (None: the plant's own default).
    disturbance : str
        What the plant's disturbance ``d_phi`` is, with units (help texts).
    Ts : float or None
        Sampling time, s, where the plant states one.
    y_phi_constraint : (low, high) or None
        The plant's output constraint, physical units, where it states one; violations are
        measured against it (else against the model's stored constraint, see
        :func:`ltv_lstm_mpc.loop.simulation.output_constraint`).
    input_labels, output_labels : tuple of str
        Names with units per input / output (plots, data files); empty: ``u_0``, ``y_0``, ...
    data_file : str
        File name ``train`` gives the identification data it generates.
    neurons : int
        Default LSTM size n of ``train`` on this plant's data.
    options : tuple of str
        Keyword options the factory accepts (e.g. ``"mismatch"`` for the pH plant).
    class_name : str
        Name of the plant class, as identification data records it.
    """

    name: str
    factory: PlantFactory
    title: str = ""
    description: str = ""
    model: str | None = None
    setpoints: tuple[str, ...] = ()
    nominal_disturbance: tuple[float, ...] | None = None
    disturbance: str = "the plant's disturbance"
    Ts: float | None = None
    y_phi_constraint: tuple[Any, Any] | None = None
    input_labels: tuple[str, ...] = ()
    output_labels: tuple[str, ...] = ()
    data_file: str = "identification_data.npz"
    neurons: int = 5
    options: tuple[str, ...] = ()
    class_name: str = ""

    def build(self, model: LSTMModel | None = None, **options: Any) -> Plant:
        """A new plant at its initial condition (``factory(model, **options)``, then
        ``reset()``).

        Raises
        ------
        UnknownPlantError
            An option the plant does not declare (the message lists those it does).
        ArgumentTypeError
            The factory returned something that is not a plant.
        """
        unknown = sorted(set(options) - set(self.options))
        if unknown:
            accepted = ", ".join(self.options) or "none"
            raise UnknownPlantError(
                f"plant {self.name!r} takes no option {', '.join(unknown)} (it accepts: {accepted})"
            )
        plant = self.factory(model, **options)
        expect_methods(
            f"plant {self.name!r}", plant, PLANT_METHODS, "a plant",
            "reset(), output() and step(u_phi, d_phi): ltv_lstm_mpc.Plant",
        )  # fmt: skip
        plant.reset()
        return plant

    def setpoints_for(self, model: LSTMModel) -> tuple[str, ...]:
        """The default set-points of this plant for ``model``: the entry's own of the model's
        output count; for a plant without signals of its own (the LSTM plant is the model
        itself) those of the registered plant whose default model has ``model``'s weights;
        empty when neither applies (then they follow from the model's admissible interval,
        :func:`ltv_lstm_mpc.paper.scenarios.admissible_setpoints`)."""
        own = tuple(t for t in self.setpoints if len(str(t).split(",")) == model.p)
        if own or self.output_labels:
            return own
        twin = plant_of_model(model)
        if twin is None:
            return ()
        return tuple(t for t in twin.setpoints if len(str(t).split(",")) == model.p)


_REGISTRY: dict[str, RegisteredPlant] = {}

FloatArray = NDArray[np.float64]

#: The methods of the plant role (:class:`~ltv_lstm_mpc.Plant`).
PLANT_METHODS = ("reset", "output", "step")


def register_plant(
    name: str,
    factory: PlantFactory,
    *,
    replace: bool = False,
    **defaults: Any,
) -> RegisteredPlant:
    """Add a plant under ``name`` (then ``--plant name`` and ``plant = "name"`` work).

    Parameters
    ----------
    name : str
        A name without ``":"`` (that form is reserved for ``"module:Class"``).
    factory : callable
        ``factory(model, **options) -> Plant``.
    replace : bool
        Allow replacing an existing entry (default: an existing name is an error).
    **defaults
        Any other field of :class:`RegisteredPlant` (``description``, ``model``,
        ``setpoints``, ``Ts``, ...).

    Returns
    -------
    RegisteredPlant
        The entry.
    """
    if not isinstance(name, str) or not name or ":" in name:
        raise UnknownPlantError(
            f"a plant name is a non-empty string without ':' (reserved for 'module:Class'), "
            f"got {name!r}"
        )
    if not callable(factory):
        raise ArgumentTypeError(f"factory of plant {name!r} must be callable, got {factory!r}")
    if name in _REGISTRY and not replace:
        raise UnknownPlantError(
            f"plant {name!r} is already registered; pass replace=True to replace it"
        )
    defaults.setdefault("title", f"plant {name}")
    entry = RegisteredPlant(name=name, factory=factory, **defaults)
    _REGISTRY[name] = entry
    return entry


def registered_plants() -> list[str]:
    """The registered plant names, sorted (``"module:Class"`` names work besides these)."""
    return sorted(_REGISTRY)


def resolve_plant(name: str) -> RegisteredPlant:
    """The entry of a registered name, or of a ``"package.module:Class"`` plant class.

    Raises
    ------
    UnknownPlantError
        An unknown name, a module that cannot be imported, a missing class, or a class
        that is not a plant; the message says which and how to fix it.
    """
    if isinstance(name, RegisteredPlant):
        return name
    if not isinstance(name, str):
        raise ArgumentTypeError(f"a plant name is a string, got {type(name).__name__}")
    if ":" in name:
        return _from_class_path(name)
    if name not in _REGISTRY:
        raise UnknownPlantError(
            f"unknown plant {name!r}: use one of {', '.join(registered_plants())}, or "
            "'package.module:Class' for a plant class importable on the Python path"
        )
    return _REGISTRY[name]


def plant_name_of(class_name: str) -> str | None:
    """The registered name whose plant class is ``class_name`` (identification data record
    the class); None when no entry has it."""
    for entry in _REGISTRY.values():
        if entry.class_name == class_name:
            return entry.name
    return None


def _from_class_path(path: str) -> RegisteredPlant:
    module_name, _, attribute = path.partition(":")
    if not module_name or not attribute:
        raise UnknownPlantError(f"plant {path!r}: write a user plant as 'package.module:Class'")
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        raise UnknownPlantError(
            f"plant {path!r}: module {module_name!r} cannot be imported ({error}); it must be "
            "importable on the Python path (set PYTHONPATH, or install the package; campaign "
            "workers need it too)"
        ) from error
    cls: Any = module
    for part in attribute.split("."):
        if not hasattr(cls, part):
            raise UnknownPlantError(
                f"plant {path!r}: module {module_name!r} has no attribute {attribute!r}"
            )
        cls = getattr(cls, part)
    if not callable(cls):
        raise UnknownPlantError(f"plant {path!r}: {attribute!r} is not a class or factory")
    missing = [m for m in PLANT_METHODS if not callable(getattr(cls, m, None))]
    if inspect.isclass(cls) and missing:
        raise UnknownPlantError(
            f"plant {path!r}: class {cls.__name__} has no {', '.join(m + '()' for m in missing)}"
            "; a plant needs reset(), output() and step(u_phi, d_phi)"
        )

    def factory(model: Any = None, **options: Any) -> Plant:
        return cls(**options)

    doc = inspect.getdoc(cls) or ""
    Ts = getattr(cls, "Ts", None)
    disturbance = getattr(cls, "nominal_disturbance", None)
    return RegisteredPlant(
        name=path,
        factory=factory,
        title=f"plant {getattr(cls, '__name__', path)}",
        description=doc.splitlines()[0] if doc else path,
        model=getattr(cls, "default_model", None),
        setpoints=tuple(str(s) for s in getattr(cls, "default_setpoints", ())),
        nominal_disturbance=None
        if disturbance is None
        else tuple(float(v) for v in _as_tuple(disturbance)),
        Ts=float(Ts) if isinstance(Ts, (int, float)) else None,
        y_phi_constraint=getattr(cls, "y_phi_constraint", None),
        input_labels=tuple(getattr(cls, "input_labels", ())),
        output_labels=tuple(getattr(cls, "output_labels", ())),
        data_file=f"{getattr(cls, '__name__', 'plant').lower()}_identification_data.npz",
        neurons=int(getattr(cls, "default_neurons", 5)),
        class_name=path,
    )


def _as_tuple(value: Any) -> tuple[Any, ...]:
    try:
        return tuple(value)
    except TypeError:
        return (value,)


# -- the plants that ship ----------------------------------------------------------------


def _ph_plant(model: Any = None, *, mismatch: Mapping[str, float] | None = None) -> Plant:
    from dataclasses import replace

    from ltv_lstm_mpc.plants.ph import PHNeutralizationPlant, PHParameters

    if mismatch is None:
        return PHNeutralizationPlant()
    nominal = PHParameters()
    params = replace(nominal, **{k: getattr(nominal, k) * v for k, v in mismatch.items()})
    return PHNeutralizationPlant(q1=params.q1, params=params)


def _lstm_plant(model: Any = None, *, y0_phi: float | None = None) -> Plant:
    from ltv_lstm_mpc.plants.lstm_plant import LSTMPlant

    if model is None:
        raise UnknownPlantError("the LSTM plant (Fig. 2) is the model itself: give the model")
    return LSTMPlant(model, y0_phi=y0_phi)


def _quadtank_plant(model: Any = None) -> Plant:
    from ltv_lstm_mpc.plants.quadtank import QUADTANK_TS, QuadrupleTankPlant

    Ts = getattr(model, "Ts", None)
    return QuadrupleTankPlant(Ts=Ts if Ts is not None else QUADTANK_TS)


register_plant("ph", _ph_plant, **PH_REGISTRY_DEFAULTS)
# The LSTM plant is the model itself: its set-points, units and initial output come from the
# model (those of the plant whose default model it is, else its admissible interval).
register_plant(
    "lstm",
    _lstm_plant,
    title="LSTM plant",
    description="the LSTM model itself with an additive output disturbance (Fig. 2)",
    model=PH_REGISTRY_DEFAULTS["model"],
    nominal_disturbance=(0.0,),
    disturbance="output offset in output units",
    options=("y0_phi",),
    class_name="LSTMPlant",
)
register_plant(
    "quadtank",
    _quadtank_plant,
    title="quadruple-tank process",
    description="quadruple-tank process (Johansson 2000): pump voltages v1, v2 (V) -> "
    "levels h1, h2 (cm); disturbance: leak areas of tanks 1 and 2 (cm^2)",
    model="quadtank_lstm_n8.npz",
    setpoints=("14,14", "13,11", "12.3,12.8"),
    nominal_disturbance=(0.0, 0.0),
    disturbance="leak areas of tanks 1 and 2 in cm^2",
    Ts=10.0,
    input_labels=("v1 (V)", "v2 (V)"),
    output_labels=("h1 (cm)", "h2 (cm)"),
    data_file="quadtank_identification_data.npz",
    y_phi_constraint=QUADTANK_LEVEL_CONSTRAINT,
    neurons=8,
    class_name="QuadrupleTankPlant",
)


# -- the registered plant of a model (its shipped weights) ---------------------------------

_SIGNATURE_NAMES = ("W_y", "b_y", "u_phi_min", "u_phi_max", "y_phi_min", "y_phi_max")


def _signature(model: LSTMModel) -> tuple[FloatArray, ...] | None:
    normalization = model.normalization
    if normalization is None:
        return None
    return (
        np.asarray(model.W_y),
        np.asarray(model.b_y),
        normalization.u_phi_min,
        normalization.u_phi_max,
        normalization.y_phi_min,
        normalization.y_phi_max,
    )


@functools.lru_cache(maxsize=8)
def _file_signature(name: str) -> tuple[FloatArray, ...] | None:
    from ltv_lstm_mpc.exceptions import LtvMpcError
    from ltv_lstm_mpc.lstm.shipped import model_path

    try:
        with np.load(model_path(name)) as data:
            return tuple(np.asarray(data[key], dtype=np.float64) for key in _SIGNATURE_NAMES)
    except (OSError, KeyError, ValueError, LtvMpcError):  # missing or foreign file: no match
        return None


def plant_of_model(model: LSTMModel) -> RegisteredPlant | None:
    """The registered plant with labels whose default model has ``model``'s weights."""
    ours = _signature(model)
    if ours is None:
        return None
    for name in registered_plants():
        entry = resolve_plant(name)
        if entry.model is None or len(entry.output_labels) != model.p:
            continue
        if len(entry.input_labels) != model.m:
            continue
        theirs = _file_signature(entry.model)
        if theirs is not None and all(
            a.shape == b.shape and np.array_equal(a, b) for a, b in zip(ours, theirs, strict=True)
        ):
            return entry
    return None
