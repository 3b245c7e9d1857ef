"""Blendshape names: the 52 ARKit names and normalisation of the spellings rigs use.

Every rig and performance in faceretarget speaks ARKit's camelCase (``eyeBlinkLeft``).  Other
spellings are normalised on load:

* ``eyeBlink_L`` / ``eyeBlink_R`` (ICT-FaceKit, many DCC rigs) -> ``eyeBlinkLeft`` / ``eyeBlinkRight``
* ``EyeBlinkLeft`` (Live Link Face CSV, Unreal) -> ``eyeBlinkLeft``
* ``eyeBlink.L``, ``eyeBlinkL``, ``eye_blink_left`` and case variants -> ``eyeBlinkLeft``

Shapes ARKit keeps whole but some rigs split into halves (``browInnerUp`` -> ``browInnerUp_L`` and
``browInnerUp_R``; ``cheekPuff`` likewise) normalise to ``browInnerUpLeft`` / ``browInnerUpRight``;
:func:`split_parent` tells which ARKit shape such a half belongs to, so a whole weight drives both
halves and two half weights average into a whole.  Names that are not ARKit shapes (``cheekRaiser_L``,
``PupilDilate_R``) are normalised the same way and kept as custom shapes.

Note that ARKit's ``jawLeft``, ``jawRight``, ``mouthLeft`` and ``mouthRight`` are *directions*, not
sides, and are never split.
"""

from __future__ import annotations

import re

__all__ = [
    "ARKIT_NAMES",
    "SPLITTABLE",
    "normalize_name",
    "split_parent",
    "is_arkit",
]

#: The 52 ARKit blendshape names in the order Live Link Face writes them.
ARKIT_NAMES: tuple[str, ...] = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft",
    "eyeSquintLeft", "eyeWideLeft", "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight",
    "eyeLookOutRight", "eyeLookUpRight", "eyeSquintRight", "eyeWideRight", "jawForward",
    "jawRight", "jawLeft", "jawOpen", "mouthClose", "mouthFunnel", "mouthPucker", "mouthRight",
    "mouthLeft", "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight",
    "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft", "mouthStretchRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthPressLeft",
    "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
    "mouthUpperUpRight", "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft",
    "browOuterUpRight", "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "noseSneerLeft",
    "noseSneerRight", "tongueOut",
)

_ARKIT_SET = frozenset(ARKIT_NAMES)
_ARKIT_LOWER = {n.lower(): n for n in ARKIT_NAMES}

#: ARKit shapes that are whole in ARKit but that some rigs split into left and right halves.
SPLITTABLE: tuple[str, ...] = ("browInnerUp", "cheekPuff", "mouthClose", "jawOpen", "mouthFunnel",
                               "mouthPucker", "mouthRollLower", "mouthRollUpper",
                               "mouthShrugLower", "mouthShrugUpper", "jawForward", "tongueOut")

# Directional ARKit shapes whose Left/Right is a direction; they must never be read as split halves.
_DIRECTIONAL = frozenset({"jawLeft", "jawRight", "mouthLeft", "mouthRight"})

_SIDE_SUFFIX = re.compile(r"^(?P<base>.*?)(?P<sep>[._\- ]?)(?P<side>left|right|l|r)$", re.IGNORECASE)


def _camel(s: str) -> str:
    """``eye_blink`` / ``Eye Blink`` / ``EyeBlink`` -> ``eyeBlink``."""
    parts = [p for p in re.split(r"[\s_\-.]+", s) if p]
    if not parts:
        return s
    if len(parts) == 1:
        p = parts[0]
        return p[:1].lower() + p[1:]
    head = parts[0][:1].lower() + parts[0][1:]
    return head + "".join(p[:1].upper() + p[1:] for p in parts[1:])


def normalize_name(name: str) -> str:
    """Return the ARKit camelCase spelling of a blendshape name.

    Examples
    --------
    >>> normalize_name("eyeBlink_L")
    'eyeBlinkLeft'
    >>> normalize_name("EyeBlinkLeft")
    'eyeBlinkLeft'
    >>> normalize_name("browInnerUp_R")
    'browInnerUpRight'
    >>> normalize_name("jawLeft")
    'jawLeft'
    >>> normalize_name("PupilDilate_L")
    'pupilDilateLeft'

    Exporters' prefixes, suffixes and namespaces around an ARKit name are removed:

    >>> normalize_name("blendshape_JawOpen"), normalize_name("blendShape1.mouthSmile_L")
    ('jawOpen', 'mouthSmileLeft')
    """
    raw = name.strip()
    if raw in _ARKIT_SET:
        return raw
    low = raw.lower()
    if low in _ARKIT_LOWER:
        return _ARKIT_LOWER[low]
    m = _SIDE_SUFFIX.match(raw)
    if m and m.group("base") and (_PREFIX.match(raw) or any(c in raw for c in ".:|/")):
        bare = _without_affixes(raw)
        if bare is not None:
            return bare
    if m and m.group("base"):
        base, sep, side = m.group("base"), m.group("sep"), m.group("side")
        word = side.lower() in ("left", "right")
        # "eyeBlinkL": a bare L/R glued on is a side only when what precedes it is a shape name
        # a rig would split; otherwise (e.g. "jawForwardR" is unlikely, "HeadR"?) keep it whole.
        if sep or word or side in ("L", "R"):
            side_word = "Left" if side.lower() in ("l", "left") else "Right"
            base_c = _camel(base.rstrip("._- "))
            cand = base_c + side_word
            cand_arkit = _ARKIT_LOWER.get(cand.lower())
            if cand_arkit is not None:
                return cand_arkit
            if sep or word:
                return cand
    bare = _without_affixes(raw)
    if bare is not None:
        return bare
    c = _camel(raw)
    return _ARKIT_LOWER.get(c.lower(), c)


#: Prefixes exporters put before a shape name ("blendshape_JawOpen", "BS_jawOpen", "ARKit_jawOpen").
_PREFIX = re.compile(r"^(?:blend[_ ]?shapes?|bs|arkit|morphs?|shapes?|face|mt)[._:\- ]*", re.IGNORECASE)
#: Suffixes likewise ("jawOpen_weight", "jawOpen.value").
_SUFFIX = re.compile(r"[._\- ]*(?:weights?|value|amount|bs)$", re.IGNORECASE)


def _without_affixes(raw: str) -> str | None:
    """The ARKit name inside a prefixed, suffixed or namespaced one (``blendShape1.jawOpen``,
    ``Face:mouthSmile_L``, ``blendshape_JawOpen``, ``jawOpen_weight``), or None."""
    cands = []
    for sep in (".", ":", "|", "/"):
        if sep in raw:
            cands.append(raw.rsplit(sep, 1)[1])
    stripped = _SUFFIX.sub("", _PREFIX.sub("", raw))
    if stripped and stripped != raw:
        cands.append(stripped)
    for c in cands:
        if c and c != raw:
            n = normalize_name(c)
            if n in _ARKIT_SET:
                return n
    return None


def split_parent(name: str) -> str | None:
    """For the half of a split shape (``browInnerUpLeft``) return the ARKit whole (``browInnerUp``).

    Returns ``None`` for anything else, including ARKit's own sided shapes (``eyeBlinkLeft``) and
    the directional ones (``jawLeft``).
    """
    if name in _ARKIT_SET:
        return None
    for side in ("Left", "Right"):
        if name.endswith(side):
            base = name[: -len(side)]
            if base in _ARKIT_SET:
                return base
    return None


def is_arkit(name: str) -> bool:
    """True when ``name`` is one of the 52 ARKit shape names (already normalised)."""
    return name in _ARKIT_SET
