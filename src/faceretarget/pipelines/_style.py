"""Emotion editing jobs: the ``style fit`` command as a library function."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path

from ..errors import InvalidDataError
from ..io import read_audio, read_performance
from ..performance import Performance
from ..style import SpeakerStyleModel, StyleModel

__all__ = ["read_style_take", "fit_style", "fit_speaker_style"]


def _quiet(*_a) -> None:
    return None


def read_style_take(path: str | os.PathLike, fps: float | None = None,
                    audio: str | os.PathLike | None = None) -> Performance:
    """A take for a style model: any take file, with the speech of ``audio`` when given."""
    perf = read_performance(path, fps=fps)
    if audio is not None:
        x, rate = read_audio(audio)
        perf = perf.replace(audio=x, audio_rate=rate)
    return perf


def fit_style(takes: Mapping[str, Performance], *, reference: str | None = None,
              added: Mapping[str, Performance] | None = None, log: Callable[..., None] = _quiet,
              **params) -> StyleModel:
    """Align takes of one text in several styles, fit a :class:`~faceretarget.style.StyleModel`,
    and learn untrained styles from more takes of the same text (Chuang Ch. 2).

    Parameters
    ----------
    takes : mapping of style name to Performance
        At least two.
    reference : str, optional
        The style the others are aligned to (default the first).
    added : mapping of style name to Performance, optional
        Untrained styles, each a take of the same text as ``reference``.
    **params
        :class:`~faceretarget.style.StyleModel` parameters.
    """
    if len(takes) < 2:
        raise InvalidDataError(f"give takes in at least 2 styles, got {len(takes)}")
    added = dict(added or {})
    clash = sorted(set(added) & set(takes))
    if clash:
        raise InvalidDataError(f"style '{clash[0]}' is both a training take and an added one")
    ref = reference or next(iter(takes))
    for k, p in takes.items():
        log(f"{k}: {p.n_frames} frames ({p.kind}) from {Path(p.source).name}"
            + (" with audio" if p.audio is not None else ""))
    model = StyleModel(**params).fit(dict(takes), reference=ref)
    log(f"settings: {model.settings_}" + (" (cross-validated on the training frames)"
                                           if model.selection_ is not None else ""))
    for k, al in model.alignments_.items():
        rate = (al.take_times[-1] - al.take_times[0]) / max(al.ref_times[-1] - al.ref_times[0], 1e-9)
        log(f"aligned {k} to {ref} by {al.by}: {len(al.path)} path steps; {k} lasts {rate:.3f} times as long")
    for k, take in added.items():
        model.add_style_take(k, take, ref, takes[ref])
        log(f"added untrained style '{k}' from {take.source} (same text as '{ref}')")
    A, S = model.asymmetric_, model.symmetric_
    log(f"PCA: {model.n_components_} components; content dims J = {A.content_dims_}, style dims I = "
        f"{S.style_dims_}; symmetric fit {S.n_iter_} iteration(s); styles: {', '.join(model.styles_)}")
    return model


def fit_speaker_style(takes: Mapping[str, Mapping[str, Performance]], *, log: Callable[..., None] = _quiet,
                      **params) -> SpeakerStyleModel:
    """A :class:`~faceretarget.style.SpeakerStyleModel` from several speakers' takes (issue 27).

    Parameters
    ----------
    takes : {speaker: {style: Performance}}
        Face takes with the tracker's scores (:func:`~faceretarget.pipelines.face_takes` with
        ``scores=True``), one text per speaker, each speaker with a neutral take.
    **params
        :class:`~faceretarget.style.SpeakerStyleModel` parameters.
    """
    for spk, d in takes.items():
        log(f"{spk}: {', '.join(f'{k} {p.n_frames}' for k, p in d.items())} frames")
    model = SpeakerStyleModel(**params).fit(takes)
    log(f"space {model.space}, intensity {model.intensity}; {len(model.speakers_)} speaker(s), styles "
        f"{', '.join(model.styles_)}")
    for e in model.styles_[1:]:
        log(f"  {e}: typical intensity {model.intensity_[e]:.3g}, carries to a new speaker x{model.gain_[e]:.2f} "
            f"({model.gain_source_[e]}); settings {model.models_[e].settings_}")
    return model
