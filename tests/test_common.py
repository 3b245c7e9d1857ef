"""The same checks over every fitted model class (in the manner of scikit-learn's estimator checks).

For each model: the constructor stores its parameters unchanged (``get_params`` round trip); a model
applied or saved before ``fit`` raises :class:`NotFittedError`; ``fit`` returns ``self`` and leaves
the parameter objects it was given unchanged; applying the model (``transform`` and the other apply
methods) leaves its whole learned state unchanged, bit for bit; and ``save``/``load`` gives a model
whose results are identical.  A model class that is not listed here fails
:func:`test_every_model_class_is_checked`.
"""

from __future__ import annotations

import copy
import dataclasses
import importlib
import inspect
import pkgutil
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest

import faceretarget
from faceretarget.base import Model, model_state, states_equal
from faceretarget.errors import NotFittedError
from faceretarget.headpose import HeadPose
from faceretarget.performance import Performance


@dataclass
class Case:
    """How to build, fit and apply one model on small synthetic data."""

    name: str
    make: Callable[[], Model]
    fit: Callable[[Model], Model]
    apply: Callable[[Model], object]


# ----------------------------------------------------------------------------------------- data
def _demo():
    from faceretarget.cloning import keymodel_pair
    from faceretarget.datasets import make_demo_character, make_demo_take

    ada, bo = make_demo_character("ada"), make_demo_character("bo")
    rom = make_demo_take(seconds=10.0, fps=30.0, seed=1)
    take = make_demo_take(seconds=3.0, fps=30.0, seed=7)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sk, tk, _ = keymodel_pair(ada, bo, "rom-10", rom=rom)
    frames = ada.evaluate(ada.map_weights(take.names, take.weights, warn=False))
    noisy = frames[:, ada.landmarks] + np.random.default_rng(0).normal(0, 0.05, (take.n_frames, 68, 3))
    return ada, bo, sk, tk, take, frames, noisy


DEMO = None


def demo():
    global DEMO
    if DEMO is None:
        DEMO = _demo()
    return DEMO


def _markers(T=80, seed=3):
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    face = rng.normal(0, 40, (10, 3))
    R = Rotation.from_rotvec(np.c_[0.2 * np.sin(np.arange(T) / 9), 0.1 * np.cos(np.arange(T) / 7), np.zeros(T)])
    X = np.einsum("tij,pj->tpi", R.as_matrix(), face) + rng.normal(0, 0.01, (T, 10, 3))
    X[:, 8:] += rng.normal(0, 2, (T, 2, 3))
    return Performance.from_points(X, [f"m{i}" for i in range(10)], fps=60.0, unit="mm", source="markers")


def _style_frames(S=3, C=60, D=12, seed=0):
    rng = np.random.default_rng(seed)
    B = rng.normal(size=(C, 3))
    A = rng.normal(size=(S, D, 3))
    return {f"s{s}": B @ A[s].T + 0.01 * rng.normal(size=(C, D)) for s in range(S)}


def _speakers():
    """Four synthetic speakers' aligned face takes with scores (``tests/test_speaker_style.py``)."""
    from test_speaker_style import speakers

    return speakers(C=30)


def _speech_take(seconds=8.0, seed=1):
    sr, fps = 16000, 30.0
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * sr)) / sr
    f0 = 140 + 30 * np.sin(2 * np.pi * 0.7 * t)
    voiced = (np.sin(2 * np.pi * 2.3 * t) > -0.2).astype(float)
    audio = (0.3 * voiced * np.sin(2 * np.pi * np.cumsum(f0) / sr) + 0.001 * rng.normal(size=t.size))
    tf = np.arange(int(seconds * fps)) / fps
    rot = np.c_[0.1 * np.sin(2 * np.pi * 0.4 * tf), 0.05 * np.sin(2 * np.pi * 0.9 * tf), 0.02 * np.cos(tf)]
    return Performance(tf, fps, head=HeadPose.from_euler("YXZ", rot, np.zeros((tf.size, 3))),
                       audio=audio.astype(np.float32), audio_rate=sr, source=f"speech{seed}")


# ----------------------------------------------------------------------------------------- cases
def _cases() -> list[Case]:
    from faceretarget.capture import AppearanceModel
    from faceretarget.cloning import CardinalBasis, ExpressionCloner, FeaturePCA, NohNeumannCloner
    from faceretarget.headmotion import HeadMotionDatabase
    from faceretarget.numerics import RigidAligner
    from faceretarget.pipelines import AppearanceStyleModel
    from faceretarget.retarget import BlendshapeRetargeter, LandmarkSolver, Regions, default_regions
    from faceretarget.style import (
        AsymmetricBilinearModel,
        ExpressionSliders,
        SpeakerStyleModel,
        StyleModel,
        SymmetricBilinearModel,
    )

    cases = []
    for method in ("temporal", "linear", "pyun"):
        cases.append(Case(f"ExpressionCloner[{method}]", lambda m=method: ExpressionCloner(m),
                          lambda c: c.fit(demo()[2], demo()[3]),
                          lambda c: c.transform(demo()[6], demo()[4].times)))
    for solver in ("signed", "nnls"):
        cases.append(Case(f"BlendshapeRetargeter[{solver}]", lambda s=solver: BlendshapeRetargeter(s),
                          lambda r: r.fit(demo()[2], demo()[3]),
                          lambda r: r.transform(demo()[6], demo()[4].times)))
    cases.append(Case("BlendshapeRetargeter[regions]",
                      lambda: BlendshapeRetargeter(regions=default_regions(demo()[0].neutral.vertices[demo()[0].landmarks],
                                                                           landmarks68=True)),
                      lambda r: r.fit(demo()[2], demo()[3]),
                      lambda r: r.transform(demo()[6], demo()[4].times)))
    cases.append(Case("BlendshapeRetargeter[markers]", lambda: BlendshapeRetargeter(features="all"),
                      lambda r: r.fit(*_marker_keys()),
                      lambda r: r.transform(_markers(seed=4))))
    cases.append(Case("Regions", lambda: Regions({"a": [0, 1], "b": [2, 3]}, width=0.5),
                      lambda g: g.fit(4, np.c_[np.zeros(6), np.arange(6.0), np.zeros(6)]),
                      lambda g: g.split(np.ones((2, 6, 3)))))
    cases.append(Case("FeaturePCA", lambda: FeaturePCA(), lambda p: p.fit(np.random.default_rng(1).normal(size=(9, 6))),
                      lambda p: p.transform(np.random.default_rng(2).normal(size=(4, 6)))))
    cases.append(Case("CardinalBasis", lambda: CardinalBasis(),
                      lambda b: b.fit(np.random.default_rng(1).normal(size=(7, 3))),
                      lambda b: b.transform(np.random.default_rng(2).normal(size=(4, 3)))))
    cases.append(Case("NohNeumannCloner", lambda: NohNeumannCloner(),
                      lambda c: c.fit(demo()[0].neutral, demo()[1].neutral, demo()[0].landmarks, demo()[1].landmarks),
                      lambda c: c.transform(demo()[5][:5])))
    cases.append(Case("LandmarkSolver", lambda: LandmarkSolver(smooth=0.5),
                      lambda m: m.fit(demo()[1], demo()[1].neutral.vertices[demo()[1].landmarks] * 100.0),
                      lambda m: m.transform(demo()[6] * 100.0, np.full((90, demo()[1].n_shapes), 0.1))))
    cases.append(Case("RigidAligner", lambda: RigidAligner(n_auto=6), lambda a: a.fit(_markers()),
                      lambda a: a.transform(_markers(seed=5))))
    cases.append(Case("StyleModel", lambda: StyleModel(variance=0.999, energy=0.999, prior=1.0, local=0),
                      lambda m: m.fit_frames(_style_frames()),
                      lambda m: m.known(_style_frames(seed=1)["s0"], "s0", "s2", warn=False)))
    cases.append(Case("StyleModel[auto]", lambda: StyleModel(),
                      lambda m: m.fit_frames(_style_frames()),
                      lambda m: m.unknown(_style_frames(seed=1)["s1"], "s2", warn=False)))
    fast = {"variance": 0.9999, "energy": 0.9999, "prior": 10.0, "local": 0}
    cases.append(Case("SpeakerStyleModel", lambda: SpeakerStyleModel(space="both", style=fast),
                      lambda m: m.fit({k: v for k, v in _speakers().items() if k != "D"}, aligned=True),
                      lambda m: m.transform(_speakers()["D"]["neutral"], "angry", 0.8)))
    cases.append(Case("AsymmetricBilinearModel", lambda: AsymmetricBilinearModel(),
                      lambda m: m.fit(np.stack(list(_style_frames().values()))),
                      lambda m: m.translate(_style_frames(seed=1)["s0"], 0, 2)))
    cases.append(Case("SymmetricBilinearModel", lambda: SymmetricBilinearModel(),
                      lambda m: m.fit(np.stack(list(_style_frames().values()))),
                      lambda m: m.infer(_style_frames(seed=1)["s1"])))
    cases.append(Case("ExpressionSliders", lambda: ExpressionSliders(),
                      lambda s: s.fit(*_slider_sets()),
                      lambda s: s.transform(_slider_sets()[0][1:] * 0.5, [0.3, 0.7])))
    cases.append(Case("HeadMotionDatabase", lambda: HeadMotionDatabase(),
                      lambda d: d.fit([_speech_take()]),
                      lambda d: d.transform(_speech_take(4.0, seed=2))))
    cases.append(Case("AppearanceModel", lambda: AppearanceModel(1.0, 0.9, width=40, points=np.arange(12)),
                      lambda m: m.fit(*_appearance_data()),
                      lambda m: m.transform(*_appearance_data(seed=1))))
    cases.append(Case("AppearanceStyleModel",
                      lambda: AppearanceStyleModel({"variance": 0.999, "energy": 0.999, "prior": 1.0, "local": 0}),
                      lambda m: m.fit_aligned(*_appearance_style_data()[:2]),
                      lambda m: m.transform(_appearance_style_data()[2], "s1", source="s0")))
    return cases


def _marker_keys():
    from faceretarget.mesh import Mesh
    from faceretarget.rig import Rig

    X = _markers().points
    keys = Rig(Mesh(X[0]), [f"f{i}" for i in (10, 30, 50)], X[[10, 30, 50]] - X[0], "mm")
    return keys, keys, [f"m{i}" for i in range(10)]


def _slider_sets():
    rng = np.random.default_rng(5)
    src = rng.normal(size=(4, 6, 3))
    return src, {"happy": rng.normal(size=(4, 9, 3)), "angry": rng.normal(size=(4, 9, 3))}


def _appearance_data(seed=0):
    rng = np.random.default_rng(seed)
    base = np.random.default_rng(0).uniform(5, 55, (12, 2))
    lm = base + rng.normal(0, 1, (12, 12, 2))
    frames = rng.integers(0, 255, (12, 64, 64, 3)).astype(np.uint8)
    return frames, lm


def _appearance_style_data():
    """An appearance model, aligned configuration vectors of three styles, and vectors to restyle."""
    from faceretarget.capture import AppearanceModel

    app = AppearanceModel(1.0, 0.9, width=40, points=np.arange(12)).fit(*_appearance_data())
    frames = _style_frames(D=len(app.names_))
    return app, frames, frames["s0"][:20] + 0.01


CASES = _cases()


# ----------------------------------------------------------------------------------------- helpers
def _arrays(out) -> list[np.ndarray]:
    """Every array in a result (ndarray, dataclass, take, tuple), in a fixed order."""
    if isinstance(out, np.ndarray):
        return [out]
    if isinstance(out, HeadPose):
        return [out.quaternions] + ([] if out.translation is None else [out.translation])
    if isinstance(out, Performance):
        return [a for c in ("times", "weights", "points", "vertices") if (a := getattr(out, c)) is not None] + (
            _arrays(out.head) if out.head is not None else [])
    if dataclasses.is_dataclass(out):       # (timings are not results)
        return [a for f in dataclasses.fields(out) if not f.name.endswith("_seconds")
                for a in _arrays(getattr(out, f.name))]
    if isinstance(out, list | tuple):
        return [a for x in out for a in _arrays(x)]
    if isinstance(out, float | int | np.floating):
        return [np.asarray(out)]
    return [a for a in _arrays(list(vars(out).values()))] if hasattr(out, "__dict__") else []


def _fitted(case: Case) -> Model:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return case.fit(case.make())


def _apply(case: Case, m: Model):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return case.apply(m)


ids = [c.name for c in CASES]


# ----------------------------------------------------------------------------------------- checks
@pytest.mark.parametrize("case", CASES, ids=ids)
def test_params_are_stored_unchanged(case):
    m = case.make()
    params = m.get_params()
    again = type(m)(**params).get_params()
    assert states_equal(model_state(type(m)(**params)), model_state(type(m)(**again)))
    assert repr(m).startswith(type(m).__name__ + "(")
    with pytest.raises(ValueError, match="no parameter"):
        m.set_params(no_such_parameter=1)


@pytest.mark.parametrize("case", CASES, ids=ids)
def test_unfitted_model_raises(case, tmp_path):
    m = case.make()
    assert not m.is_fitted
    with pytest.raises(NotFittedError, match="fit"):
        _apply(case, m)
    with pytest.raises(NotFittedError):
        m.save(tmp_path / "m.npz")
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("case", CASES, ids=ids)
def test_fit_returns_self_and_keeps_its_parameters(case):
    m = case.make()
    before = model_state(copy.deepcopy(m))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert case.fit(m) is m
    assert m.is_fitted
    unfitted = type(m)(**m.get_params())
    assert states_equal(model_state(unfitted), before), "fit changed a parameter object it was given"


@pytest.mark.parametrize("case", CASES, ids=ids)
def test_applying_the_model_leaves_it_unchanged(case):
    m = _fitted(case)
    before = model_state(m)
    out1 = _apply(case, m)
    out2 = _apply(case, m)
    assert states_equal(model_state(m), before), "applying the model changed its state"
    a1, a2 = _arrays(out1), _arrays(out2)
    assert a1 and len(a1) == len(a2)
    for x, y in zip(a1, a2, strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("case", CASES, ids=ids)
def test_save_load_round_trip_gives_identical_results(case, tmp_path):
    m = _fitted(case)
    path = m.save(tmp_path / "model.npz")
    assert path == tmp_path / "model.npz" and path.is_file()
    back = type(m).load(path)
    assert type(back) is type(m)
    assert states_equal(model_state(back), model_state(m))
    for x, y in zip(_arrays(_apply(case, m)), _arrays(_apply(case, back)), strict=True):
        np.testing.assert_array_equal(x, y)
    assert Model.load(path).get_params().keys() == m.get_params().keys()


def test_the_checks_catch_a_model_that_mutates_when_applied():
    """A model that stores a diagnostic while applied, as ``transform`` used to, is caught."""

    class Leaky(Model):
        def __init__(self, k: int = 1):
            self.k = k

        def fit(self, X):
            self.mean_ = np.mean(X, axis=0)
            return self

        def transform(self, X):
            self._check_fitted()
            self.last_residual_ = np.asarray(X) - self.mean_
            return self.last_residual_

    m = Leaky().fit(np.ones((3, 2)))
    before = model_state(m)
    m.transform(np.zeros((2, 2)))
    assert not states_equal(model_state(m), before)


def _all_model_classes() -> set[type]:
    found = set()
    for info in pkgutil.walk_packages(faceretarget.__path__, "faceretarget."):
        if info.name.startswith("faceretarget.cli"):
            continue
        mod = importlib.import_module(info.name)
        for _, obj in inspect.getmembers(mod, inspect.isclass):
            if issubclass(obj, Model) and obj is not Model and obj.__module__ == mod.__name__ \
                    and not inspect.isabstract(obj) and not obj.__name__.startswith("_"):
                found.add(obj)
    return found


def test_every_model_class_is_checked():
    from faceretarget.style import BilinearModel

    checked = {type(c.make()) for c in CASES}
    missing = {c.__name__ for c in _all_model_classes() - checked - {BilinearModel}}
    assert not missing, f"add these models to tests/test_common.py: {sorted(missing)}"
