"""Emotion and viseme key-expressions as ARKit weight vectors (Pyun et al. 2003, Sec. 2).

Pyun et al. build their example key-models from two families: *emotional* key-models (neutral,
happy, sad, surprised, afraid, angry) and *verbal* key-models, one per viseme.  Their animators
sculpted these by hand; here they are written once as ARKit blendshape weights so that the same
key-expressions can be generated for any ARKit-style rig (see
:func:`faceretarget.cloning.composition.build_key_models`).

:data:`EMOTIONS`
    The six emotions of Pyun et al., each built from Ekman & Friesen's FACS prototype (the action
    units, AUs, that the emotion's prototype shows) mapped onto the ARKit shapes that move the same
    way.  ARKit has no shape for every AU, so each entry's comments say which shape stands in.
:data:`VISEMES`
    Thirteen visemes covering English speech.  They are the Oculus/Meta lip-sync viseme set (which
    follows the MPEG-4 viseme groups) without two of its fifteen:

    * ``sil`` (silence) is the rest face, which the ``neutral`` emotion already is; keeping it would
      make the 6 emotion x viseme composites with ``sil`` exact duplicates of the 6 pure emotions.
    * ``nn`` (n, l) puts the tongue tip on the alveolar ridge exactly as ``DD`` (t, d) does; with the
      tongue not modelled (many rigs, ICT-FaceKit included, have no ``tongueOut``) the lips and jaw
      of the two are the same, so ``DD`` covers n and l as well.

    Viseme entries use only mouth, jaw and cheek shapes, so the upper face is left to the emotion.

Weights are in [0, 1], and every sided shape is given the same weight on the left and the right.
Whole ARKit shapes that some rigs split into halves (``browInnerUp``) are written whole; they drive
both halves (see :func:`weight_vector`).

The weights were chosen for a neutral, moderate intensity of each expression (a full-strength
prototype at weight 1 tends to be a caricature on blendshape rigs) and checked on the ICT-FaceKit
rig; for example the closed-lip viseme ``PP`` opens the jaw by 0.1 and closes the lips by 0.07 of
ARKit's ``mouthClose`` (which exists to cancel ``jawOpen`` at the lips), so that the lips stay sealed
while pressed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..errors import MissingShapeError
from ..names import normalize_name

__all__ = [
    "EMOTIONS",
    "VISEMES",
    "weight_vector",
    "emotion_vectors",
    "viseme_vectors",
    "combined_weight_vectors",
    "table_shapes",
]


def _sym(shape: str, w: float) -> dict[str, float]:
    """``{shapeLeft: w, shapeRight: w}``: a sided ARKit shape at the same weight on both sides."""
    return {shape + "Left": w, shape + "Right": w}


#: The six emotional key-expressions of Pyun et al. 2003 as ARKit weights, in their order.
EMOTIONS: dict[str, dict[str, float]] = {
    # The rest face: no shape active.  Composites with it are the pure visemes.
    "neutral": {},
    "happy": {
        # AU6 cheek raiser (orbicularis oculi, pars orbitalis): the cheeks lift and bag the lower
        # lids.  cheekSquint is ARKit's AU6; 0.6 gives a clear Duchenne smile without shutting the eye.
        **_sym("cheekSquint", 0.6),
        # AU6 also narrows the eye from below; a little eyeSquint (0.3) adds the crow's-feet
        # tension that cheekSquint alone leaves out on most rigs.
        **_sym("eyeSquint", 0.3),
        # AU12 lip corner puller (zygomaticus major): the smile itself, strong (0.8) since it is the
        # defining AU of happiness; kept below 1 so composites with spread visemes still have room.
        **_sym("mouthSmile", 0.8),
    },
    "sad": {
        # AU1 inner brow raiser (frontalis, medial): the key sign of sadness; 0.7.
        "browInnerUp": 0.7,
        # AU4 brow lowerer (corrugator): with AU1 it draws the inner brows together and up into the
        # oblique "grief" brow.  Only 0.3 because ARKit's browDown also lowers the brow, fighting AU1.
        **_sym("browDown", 0.3),
        # AU15 lip corner depressor (depressor anguli oris): corners pulled down, 0.6.
        **_sym("mouthFrown", 0.6),
        # AU17 chin raiser (mentalis): pushes the chin boss and lower lip up (the pout of sadness);
        # mouthShrugLower is ARKit's AU17; 0.3 as it is the optional, weaker part of the prototype.
        "mouthShrugLower": 0.3,
    },
    "surprised": {
        # AU1 inner brow raiser: the whole brow goes up in surprise; 0.8.
        "browInnerUp": 0.8,
        # AU2 outer brow raiser (frontalis, lateral): with AU1, the high curved brow; 0.8.
        **_sym("browOuterUp", 0.8),
        # AU5B upper lid raiser at intensity B ("slight"): eyes opened a little, so 0.4 of eyeWide.
        **_sym("eyeWide", 0.4),
        # AU26 jaw drop: the jaw hangs open and the lips part without tension; 0.3 of jawOpen is a
        # moderate drop that stays clearly below the speech vowel "aa".
        "jawOpen": 0.3,
    },
    "afraid": {
        # AU1 inner brow raiser: 0.7, like sadness.
        "browInnerUp": 0.7,
        # AU2 outer brow raiser: weaker than in surprise (0.4), so with AU4 the brows end up raised
        # but flattened and drawn together, the fear brow.
        **_sym("browOuterUp", 0.4),
        # AU4 brow lowerer: 0.3, drawing the raised brows together (as in sadness).
        **_sym("browDown", 0.3),
        # AU5 upper lid raiser: stronger than in surprise (0.7): the staring, white-showing eyes of fear.
        **_sym("eyeWide", 0.7),
        # AU20 lip stretcher (risorius): the lips are pulled sideways and tense; 0.6 of mouthStretch.
        **_sym("mouthStretch", 0.6),
        # AU26 jaw drop: a small opening (0.2), less than surprise; the stretched lips stay tense.
        "jawOpen": 0.2,
    },
    "angry": {
        # AU4 brow lowerer: the brows pulled down and together, the defining AU of anger; 0.8.
        **_sym("browDown", 0.8),
        # AU5 upper lid raiser: the glare; modest (0.3) because AU7 tenses the lids at the same time.
        **_sym("eyeWide", 0.3),
        # AU7 lid tightener (orbicularis oculi, pars palpebralis): lower lids raised and tense; 0.5.
        **_sym("eyeSquint", 0.5),
        # AU23 lip tightener (orbicularis oris): the red of the lips narrows.  ARKit has no lip
        # tightener; rolling both lips in a little (0.2 each) thins the visible lips the same way.
        "mouthRollLower": 0.2,
        "mouthRollUpper": 0.2,
        # AU24 lip presser: lips pressed firmly together; mouthPress is ARKit's AU24; 0.6.
        **_sym("mouthPress", 0.6),
    },
}

#: Thirteen viseme key-expressions (Oculus/MPEG-4 groups without ``sil`` and ``nn``), as ARKit weights.
VISEMES: dict[str, dict[str, float]] = {
    # p, b, m: both lips closed and pressed.  The jaw drops a little (0.1) as in running speech, and
    # mouthClose (0.07) cancels it at the lips; mouthPress (0.3) and a slight inward roll of the lower
    # lip (0.15) make the seal firm, as before a plosive release.  On ICT-FaceKit this brings the
    # inner lips from the neutral's 0.8 mm apart to touching (gap about 0).
    "PP": {"jawOpen": 0.1, "mouthClose": 0.07, **_sym("mouthPress", 0.3), "mouthRollLower": 0.15},
    # f, v: the lower lip is drawn up and in under the upper incisors (rolled in, 0.55, and pushed up
    # by a slight shrug, 0.15); the upper lip lifts a little (0.25) to bare the teeth; jaw almost shut.
    "FF": {"jawOpen": 0.05, "mouthRollLower": 0.55, "mouthShrugLower": 0.15, **_sym("mouthUpperUp", 0.25)},
    # th (thin, this): the tongue tip shows between the teeth, so the lips part evenly, the upper lip
    # up (0.15) and the lower lip down (0.15), with a small jaw opening (0.12).
    "TH": {"jawOpen": 0.12, **_sym("mouthUpperUp", 0.15), **_sym("mouthLowerDown", 0.15)},
    # t, d (and n, l): tongue tip on the alveolar ridge; the teeth are close (jaw 0.2) and the lips
    # relaxed and slightly spread (stretch 0.2), showing a narrow slit.
    "DD": {"jawOpen": 0.2, **_sym("mouthStretch", 0.2)},
    # k, g (ng): back of the tongue on the soft palate; the jaw opens more than for DD (0.25) and the
    # lower lip relaxes down (0.15), lips only slightly spread (0.1).
    "kk": {"jawOpen": 0.25, **_sym("mouthLowerDown", 0.15), **_sym("mouthStretch", 0.1)},
    # ch, j, sh, zh: lips pushed forward and flared into a square funnel (funnel 0.5, pucker 0.2)
    # with the teeth nearly together (jaw 0.1); both lips lift off the teeth (0.15 up, 0.15 down).
    "CH": {
        "jawOpen": 0.1,
        "mouthFunnel": 0.5,
        "mouthPucker": 0.2,
        **_sym("mouthUpperUp", 0.15),
        **_sym("mouthLowerDown", 0.15),
    },
    # s, z: teeth almost closed (jaw 0.05) and shown through lips spread wide (stretch 0.35, a faint
    # smile 0.15), the lips slightly apart (0.1 up, 0.1 down).
    "SS": {
        "jawOpen": 0.05,
        **_sym("mouthStretch", 0.35),
        **_sym("mouthSmile", 0.15),
        **_sym("mouthUpperUp", 0.1),
        **_sym("mouthLowerDown", 0.1),
    },
    # r: lips slightly rounded and protruded, less than for u (pucker 0.35, funnel 0.2), jaw 0.1.
    "RR": {"jawOpen": 0.1, "mouthPucker": 0.35, "mouthFunnel": 0.2},
    # aa (father, hot): the open vowel; the jaw drops far (0.6) and both lips open with it
    # (lower lip down 0.15, upper lip up 0.1).
    "aa": {"jawOpen": 0.6, **_sym("mouthLowerDown", 0.15), **_sym("mouthUpperUp", 0.1)},
    # E (bed, say): half-open, spread: jaw 0.35, lips stretched (0.3) with a slight smile (0.1).
    "E": {"jawOpen": 0.35, **_sym("mouthStretch", 0.3), **_sym("mouthSmile", 0.1)},
    # I / ih (see, bit): close, spread vowel: jaw nearly shut (0.15), lips spread wide (stretch 0.4,
    # smile 0.3) into a thin horizontal opening.
    "I": {"jawOpen": 0.15, **_sym("mouthStretch", 0.4), **_sym("mouthSmile", 0.3)},
    # O (go, thought): rounded, open: jaw 0.4 and lips in an open round funnel (0.6) slightly
    # puckered (0.2).
    "O": {"jawOpen": 0.4, "mouthFunnel": 0.6, "mouthPucker": 0.2},
    # U / ou (boot, you): close, tightly rounded and protruded lips (pucker 0.8, a little funnel 0.2 to
    # keep a small opening), jaw nearly shut (0.1).
    "U": {"jawOpen": 0.1, "mouthPucker": 0.8, "mouthFunnel": 0.2},
}


# ---------------------------------------------------------------------------------------------- helpers
def table_shapes() -> list[str]:
    """The ARKit shapes that :data:`EMOTIONS` and :data:`VISEMES` use, in order of first use."""
    out: dict[str, None] = {}
    for table in (EMOTIONS, VISEMES):
        for entry in table.values():
            for k in entry:
                out.setdefault(normalize_name(k), None)
    return list(out)


def weight_vector(entry: Mapping[str, float], names: Sequence[str]) -> np.ndarray:
    """Map one table entry onto an ordered list of shape names.

    Parameters
    ----------
    entry : mapping of str to float
        Shape name (any spelling, see :func:`faceretarget.names.normalize_name`) to weight.
    names : sequence of str
        The shape order of the result (any spelling), for example
        :data:`faceretarget.names.ARKIT_NAMES` or a rig's ``names``.

    Returns
    -------
    (K,) float
        ``K = len(names)``; shapes the entry does not mention are 0.  A whole ARKit shape
        (``browInnerUp``) that ``names`` only has as halves (``browInnerUpLeft``/``Right``) drives
        both halves.

    Raises
    ------
    MissingShapeError
        (a ``KeyError``) naming every key of ``entry`` that is not in ``names``.

    Examples
    --------
    >>> weight_vector({"jawOpen": 0.5, "eyeBlink_L": 1.0}, ["eyeBlinkLeft", "jawOpen"])
    array([1. , 0.5])
    """
    index = {normalize_name(n): i for i, n in enumerate(names)}
    w = np.zeros(len(names))
    unknown = []
    for key, value in entry.items():
        n = normalize_name(key)
        if n in index:
            w[index[n]] = value
        elif n + "Left" in index and n + "Right" in index:
            w[index[n + "Left"]] = value
            w[index[n + "Right"]] = value
        else:
            unknown.append(key)
    if unknown:
        raise MissingShapeError(
            f"table entry has shape(s) not among the {len(names)} names: {', '.join(unknown)}"
        )
    return w


def _vectors(table: Mapping[str, Mapping[str, float]], names: Sequence[str]) -> tuple[list[str], np.ndarray]:
    labels = list(table)
    W = np.stack([weight_vector(table[k], names) for k in labels]) if labels else np.zeros((0, len(names)))
    return labels, W


def emotion_vectors(names: Sequence[str]) -> tuple[list[str], np.ndarray]:
    """The six emotions (``emotions6``, neutral = all zeros first) as weight vectors.

    Parameters
    ----------
    names : sequence of str
        Shape order of the columns.

    Returns
    -------
    labels : list of str
        ``["neutral", "happy", "sad", "surprised", "afraid", "angry"]``.
    weights : (6, K) float
    """
    return _vectors(EMOTIONS, names)


def viseme_vectors(names: Sequence[str]) -> tuple[list[str], np.ndarray]:
    """The thirteen visemes (``visemes13``) as weight vectors.

    Parameters
    ----------
    names : sequence of str
        Shape order of the columns.

    Returns
    -------
    labels : list of str
        ``["PP", "FF", "TH", "DD", "kk", "CH", "SS", "RR", "aa", "E", "I", "O", "U"]``.
    weights : (13, K) float
    """
    return _vectors(VISEMES, names)


def combined_weight_vectors(names: Sequence[str]) -> tuple[list[str], np.ndarray]:
    """The ``combined84`` set: every emotion with every viseme, then the pure emotions.

    Rows ``e * 13 + v`` (``e`` over :data:`EMOTIONS`, ``v`` over :data:`VISEMES`) are the sum of the
    two weight vectors clipped to [0, 1] and labelled ``"happy+aa"``; the last six rows are the pure
    emotions, labelled ``"happy"`` (``"neutral"`` is all zeros).  The ``neutral+<viseme>`` rows are the
    pure visemes.  The order matches
    :func:`faceretarget.cloning.composition.build_key_models`.

    Parameters
    ----------
    names : sequence of str
        Shape order of the columns.

    Returns
    -------
    labels : list of str
        84 labels.
    weights : (84, K) float in [0, 1]
    """
    e_labels, E = emotion_vectors(names)
    v_labels, V = viseme_vectors(names)
    both = np.clip(E[:, None, :] + V[None, :, :], 0.0, 1.0).reshape(-1, E.shape[1])
    labels = [f"{e}+{v}" for e in e_labels for v in v_labels] + e_labels
    return labels, np.concatenate([both, E], axis=0)
