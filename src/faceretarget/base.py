"""``Model``: the one protocol of every fitted model, and its one file format.

In the manner of scikit-learn's estimators:

* configuration only in ``__init__``, stored unchanged under the argument's name
  (:meth:`Model.get_params`, :meth:`Model.set_params`);
* ``fit(...)`` learns and returns ``self``; everything learned is an attribute ending in ``_``
  (``names_``, ``basis_``); ``fit`` never changes a parameter object it was given;
* applying a model (``transform``) never changes it: diagnostics of one application come back in
  the returned result, not as attributes;
* a model applied before ``fit`` raises :class:`~faceretarget.errors.NotFittedError`;
* ``save(path)`` writes the parameters and the learned state to one ``.npz`` and returns the path;
  ``Model.load(path)`` (on the class) gives back a model whose results are identical.

File format (``.npz``, no pickles, :func:`faceretarget.files.save_npz_arrays`)
-----------------------------------------------------------------------------
``__model__`` holds one JSON document::

    {"format": "faceretarget.model", "version": 1, "class": "faceretarget.cloning._cloner.ExpressionCloner",
     "params": {...}, "state": {...}}

``params`` and ``state`` are the constructor arguments and the learned attributes.  Numbers, strings,
lists and ``None`` are JSON; every array is stored as its own ``.npz`` entry and referenced as
``{"$array": "state.basis_"}``; a tuple is ``{"$tuple": [...]}``, a dict ``{"$dict": {...}}``, a
dataclass (a :class:`~faceretarget.Rig`, a :class:`~faceretarget.Mesh`) ``{"$dataclass": "module.Class",
"fields": {...}}``, a sparse matrix ``{"$csr": {...}}``, a head pose ``{"$headpose": {...}}`` and a nested model ``{"$model": "module.Class", "params": ..., "state": ...}``.
Only classes of this package are ever rebuilt from a file.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from scipy import sparse

from .errors import InputFileError, InvalidDataError, NotFittedError
from .headpose import HeadPose
from .performance import Performance
from .timebase import infer_fps

__all__ = ["Model", "WeightsResult", "FORMAT", "VERSION", "model_state", "states_equal"]

FORMAT = "faceretarget.model"
VERSION = 1
_KEY = "__model__"


def _class_path(obj) -> str:
    cls = obj if isinstance(obj, type) else type(obj)
    return f"{cls.__module__}.{cls.__qualname__}"


def _import_class(path: str, where: str):
    if not path.startswith("faceretarget."):
        raise InputFileError(f"{where}: refers to class {path!r}, which is not faceretarget's")
    mod, _, name = path.rpartition(".")
    try:
        return getattr(importlib.import_module(mod), name)
    except (ImportError, AttributeError) as e:
        raise InputFileError(f"{where}: class {path!r} does not exist in this faceretarget ({e})") from e


# ------------------------------------------------------------------------------------ encoding
def _encode(obj: Any, arrays: dict[str, np.ndarray], key: str) -> Any:
    if isinstance(obj, np.ndarray):
        arrays[key] = obj
        return {"$array": key}
    if isinstance(obj, np.generic):
        return obj.item()
    if obj is None or isinstance(obj, bool | int | float | str):
        return obj
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, tuple):
        return {"$tuple": [_encode(v, arrays, f"{key}.{i}") for i, v in enumerate(obj)]}
    if isinstance(obj, list):
        return [_encode(v, arrays, f"{key}.{i}") for i, v in enumerate(obj)]
    if isinstance(obj, dict):
        if not all(isinstance(k, str) for k in obj):
            raise TypeError(f"{key}: only dicts with string keys can be saved")
        return {"$dict": {k: _encode(v, arrays, f"{key}.{k}") for k, v in obj.items()}}
    if isinstance(obj, Model):
        return {"$model": _class_path(obj), "params": _encode(obj.get_params(), arrays, f"{key}.params"),
                "state": _encode(obj._state(), arrays, f"{key}.state")}
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        fields = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.init}
        return {"$dataclass": _class_path(obj), "fields": _encode(fields, arrays, key)}
    if sparse.issparse(obj):
        m = sparse.csr_matrix(obj)
        return {"$csr": {"data": _encode(m.data, arrays, f"{key}.data"),
                         "indices": _encode(m.indices, arrays, f"{key}.indices"),
                         "indptr": _encode(m.indptr, arrays, f"{key}.indptr"), "shape": list(m.shape)}}
    if isinstance(obj, HeadPose):
        return {"$headpose": {"quaternions": _encode(obj.quaternions, arrays, f"{key}.q"),
                              "translation": _encode(obj.translation, arrays, f"{key}.t"), "source": obj.source}}
    raise TypeError(f"{key}: cannot save a {type(obj).__name__}")


def _decode(node: Any, arrays: dict[str, np.ndarray], where: str) -> Any:
    if isinstance(node, list):
        return [_decode(v, arrays, where) for v in node]
    if not isinstance(node, dict):
        return node
    if "$array" in node:
        return arrays[node["$array"]]
    if "$tuple" in node:
        return tuple(_decode(v, arrays, where) for v in node["$tuple"])
    if "$dict" in node:
        return {k: _decode(v, arrays, where) for k, v in node["$dict"].items()}
    if "$model" in node:
        cls = _import_class(node["$model"], where)
        return cls._from_parts(_decode(node["params"], arrays, where), _decode(node["state"], arrays, where))
    if "$dataclass" in node:
        cls = _import_class(node["$dataclass"], where)
        return cls(**_decode(node["fields"], arrays, where))
    if "$csr" in node:
        c = node["$csr"]
        return sparse.csr_matrix((arrays[c["data"]["$array"]], arrays[c["indices"]["$array"]],
                                  arrays[c["indptr"]["$array"]]), shape=tuple(c["shape"]))
    if "$headpose" in node:
        h = node["$headpose"]
        return HeadPose(_decode(h["quaternions"], arrays, where), _decode(h["translation"], arrays, where),
                        source=h["source"])
    raise InputFileError(f"{where}: malformed model file (unknown entry {sorted(node)[:3]})")


def model_state(model: Model) -> tuple[Any, dict[str, np.ndarray]]:
    """``(tree, arrays)``: a model's parameters and learned state as they would be saved."""
    arrays: dict[str, np.ndarray] = {}
    tree = _encode(model, arrays, "model")
    return tree, arrays


def states_equal(a: tuple[Any, dict], b: tuple[Any, dict]) -> bool:
    """Whether two :func:`model_state` snapshots are identical (arrays bit for bit, NaN equal to NaN)."""
    if a[0] != b[0] or a[1].keys() != b[1].keys():
        return False
    for k, x in a[1].items():
        y = b[1][k]
        if x.shape != y.shape or x.dtype != y.dtype:
            return False
        if x.dtype.kind in "fc":
            if not np.array_equal(x, y, equal_nan=True):
                return False
        elif not np.array_equal(x, y):
            return False
    return True


# ------------------------------------------------------------------------------------ the protocol
class Model:
    """Base class of every fitted model (module docstring).

    Subclasses store each ``__init__`` argument unchanged under its own name, learn attributes
    ending in ``_`` in ``fit``, list fit-time diagnostics that are not worth saving in
    ``_transient``, and recompute private caches in :meth:`_after_load`.
    """

    #: Learned attributes that ``save`` leaves out (diagnostics of the fit, caches).
    _transient: tuple[str, ...] = ()

    # -------------------------------------------------------------------------- parameters
    @classmethod
    def _param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        return [p.name for p in sig.parameters.values()
                if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]

    def get_params(self) -> dict[str, Any]:
        """The constructor arguments, by name."""
        return {k: getattr(self, k) for k in self._param_names()}

    def set_params(self, **params) -> Model:
        """Change constructor arguments (the model must be fitted again); returns self."""
        valid = set(self._param_names())
        bad = sorted(set(params) - valid)
        if bad:
            raise ValueError(f"{type(self).__name__} has no parameter(s) {', '.join(bad)}; "
                             f"it has {', '.join(sorted(valid))}")
        for k, v in params.items():
            setattr(self, k, v)
        return self

    def __repr__(self) -> str:
        init = inspect.signature(type(self).__init__).parameters
        changed = []
        for k, v in self.get_params().items():
            default = init[k].default
            same = default is not inspect.Parameter.empty and (
                default is v or (type(default) is type(v) and not isinstance(v, np.ndarray) and default == v))
            if not same:
                changed.append(f"{k}={v!r}" if not isinstance(v, np.ndarray) else f"{k}=array{v.shape}")
        return f"{type(self).__name__}({', '.join(changed)})"

    # -------------------------------------------------------------------------- fitted state
    def _state(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items()
                if k.endswith("_") and not k.startswith("_") and k not in self._transient}

    @property
    def is_fitted(self) -> bool:
        """True once ``fit`` (or ``load``) has run."""
        return any(k.endswith("_") and not k.startswith("_") for k in vars(self))

    def _check_fitted(self, what: str = "transform") -> None:
        if not self.is_fitted:
            raise NotFittedError(f"{type(self).__name__}: call fit() before {what}()")

    def _after_load(self) -> None:
        """Rebuild private caches from the learned state (called by :meth:`load`)."""

    @classmethod
    def _from_parts(cls, params: dict, state: dict) -> Model:
        obj = cls(**params)
        for k, v in state.items():
            setattr(obj, k, v)
        obj._after_load()
        return obj

    # -------------------------------------------------------------------------- files
    def save(self, path: str | os.PathLike) -> Path:
        """Write the model to ``path`` (``.npz``, module docstring), whole or not at all; returns the path."""
        from .files import check_output_path, save_npz_arrays

        self._check_fitted("save")
        path = check_output_path(path)
        arrays: dict[str, np.ndarray] = {}
        doc = {"format": FORMAT, "version": VERSION, "class": _class_path(self),
               "params": _encode(self.get_params(), arrays, "params"),
               "state": _encode(self._state(), arrays, "state")}
        arrays[_KEY] = np.array(json.dumps(doc))
        return save_npz_arrays(path, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike):
        """Read a model written by :meth:`save` (of this class or a subclass).

        Raises
        ------
        InputFileError
            Missing or unreadable file, not a faceretarget model, a model of another class, or a
            file written by a newer faceretarget.
        """
        from .files import load_npz_arrays

        path = Path(path)
        arrays = load_npz_arrays(path)
        if _KEY not in arrays:
            raise InputFileError(f"{path}: not a faceretarget model file (no '{_KEY}' entry); models are "
                                 f"written by {cls.__name__}.save() and the 'fit'/'build' commands")
        try:
            doc = json.loads(str(arrays.pop(_KEY)))
        except ValueError as e:
            raise InputFileError(f"{path}: malformed model description ({e})") from e
        if doc.get("format") != FORMAT:
            raise InputFileError(f"{path}: not a faceretarget model file")
        if int(doc.get("version", 0)) > VERSION:
            raise InputFileError(f"{path}: written by a newer faceretarget (model format {doc['version']}, "
                                 f"this one reads {VERSION})")
        kls = _import_class(doc["class"], str(path))
        if not (isinstance(kls, type) and issubclass(kls, cls)):
            raise InputFileError(f"{path}: holds a {doc['class'].rsplit('.', 1)[-1]}, not a {cls.__name__}")
        try:
            params = _decode(doc["params"], arrays, str(path))
            state = _decode(doc["state"], arrays, str(path))
            return kls._from_parts(params, state)
        except (KeyError, TypeError, ValueError) as e:
            raise InputFileError(f"{path}: malformed {kls.__name__} file ({e})") from e


class WeightsResult:
    """Mixin of the results that hold key weights for a take (``CloneResult``, ``RetargetResult``).

    The dataclass using it has ``weights`` ``(T, N)``, ``names``, ``times`` ``(T,)`` (or None),
    ``head``, ``audio``, ``audio_rate`` and ``source``; ``default_fps`` is the rate assumed when the
    times do not show one.  ``timecode``, ``timecode_rate``, ``curves`` and ``curve_names`` (the
    input take's clock and extra curves such as Live Link Face's eye angles,
    :class:`~faceretarget.performance.Performance`) are None / empty unless :meth:`carry` set them.
    """

    default_fps = 30.0
    timecode: float | None = None
    timecode_rate: float | None = None
    curves: np.ndarray | None = None
    curve_names: tuple[str, ...] | list[str] = ()

    def carry(self, take: Performance) -> None:
        """Take over what ``take`` holds besides its face: head, audio, source, timecode and curves."""
        self.head, self.audio, self.audio_rate, self.source = take.head, take.audio, take.audio_rate, take.source
        self.timecode, self.timecode_rate = take.timecode, take.timecode_rate
        self.curves, self.curve_names = take.curves, list(take.curve_names)

    @property
    def take(self) -> Performance:
        """The weights as a take on the target keys, with the input's head motion, audio, timecode and curves."""
        if self.times is None:
            raise InvalidDataError(f"{self.source}: frames were given without times; pass times= to transform")
        return Performance(self.times, infer_fps(self.times, default=self.default_fps), weights=self.weights,
                           names=list(self.names), head=self.head, audio=self.audio, audio_rate=self.audio_rate,
                           source=self.source, timecode=self.timecode, timecode_rate=self.timecode_rate,
                           curves=self.curves, curve_names=list(self.curve_names))
