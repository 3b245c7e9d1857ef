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
    "JOINT_ROLES",
    "joint_role",
    "find_joints",
    "marker_region",
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
    ix = _INDEXED.match(raw)                            # a numbered set: "AK_25_JawOpen", "SR_21_Jaw_Open"
    if ix:
        inner = normalize_name(ix.group("rest"))
        if inner in _ARKIT_SET:
            return inner
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
#: A numbered set's prefix before the shape name ("AK_25_JawOpen", "SR_21_Jaw_Open", "A25_JawOpen").
_INDEXED = re.compile(r"^[A-Za-z]{1,3}_?\d{1,3}[_ .\-]+(?P<rest>[A-Za-z].*)$")
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
    for c in list(cands) + [raw]:                       # a numbered set's index: "AK_25_JawOpen", "A25_JawOpen"
        m = _INDEXED.match(c)
        if m:
            cands.append(m.group("rest"))
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


# ------------------------------------------------------------------------------------------ joints
#: The skeleton joints a face animation uses, by role.
JOINT_ROLES: tuple[str, ...] = ("head", "neck", "jaw", "leftEye", "rightEye")

#: Exporters' namespaces and prefixes before a joint's own name: Mixamo (``mixamorig:Head``), 3ds Max
#: Biped (``Bip01 Head``, ``Bip001_Head``), VRoid (``J_Bip_C_Head``, ``J_Adj_L_FaceEye``), Rigify
#: (``DEF-``, ``ORG-``), Character Creator (``CC_Base_``), Reallusion (``RL_``), Auto-Rig Pro (``c_``).
_JOINT_PREFIX = re.compile(
    r"^(?:mixamorig\d*|bip\d*|j_bip_[clr]|j_adj_[clr]|j_sec_[clr]|def|org|mch|cc_base|rl|c|b|bn|bone|jnt|"
    r"joint|armature|rig|skel(?:eton)?|root)(?:[_\- .:]+|(?=(?-i:[A-Z])))", re.IGNORECASE)
_JOINT_SUFFIX = re.compile(r"(?:[_\- .]+(?:jnt|joint|bind|bnd|bone|m|x|c|def|sk|skin))+$", re.IGNORECASE)
#: Words that make a joint an end, helper or twist rather than the joint itself.
_JOINT_NOT = re.compile(r"(?:end|top|tip|nub|twist|roll|target|ik|pole|ctrl|control|helper|null|socket|"
                        r"nose|lid|brow|lash|mouth|lip|teeth|tongue|ear|hair)", re.IGNORECASE)
_EYE = re.compile(r"^(?:face)?eye(?:ball)?(?:root)?$", re.IGNORECASE)
#: Rigify's metarig names its neck and head ``spine.004`` .. ``spine.006``.
_RIGIFY = {"spine.006": "head", "spine.004": "neck"}


def _joint_words(name: str) -> tuple[str, str | None]:
    """A joint name without namespace, exporter prefix and suffix, as ``(core, side)``: ``core``
    lower-case with separators removed, ``side`` ``"left"`` / ``"right"`` / None."""
    s = re.split(r"[:|/]", name.strip())[-1]
    side = None
    m = re.match(r"^j_(?:bip|adj|sec)_([lr])_", s, re.IGNORECASE)      # VRoid: J_Adj_L_FaceEye
    if m:
        side = "left" if m.group(1).lower() == "l" else "right"
    for _ in range(3):
        t = _JOINT_PREFIX.sub("", s, count=1)
        if t == s or not t:
            break
        s = t
    s = _JOINT_SUFFIX.sub("", s) or s
    m = (re.match(r"^(?P<pre>left|right|l|r)[_\- .]+(?P<rest>.+)$", s, re.IGNORECASE)
         or re.match(r"^(?P<pre>Left|Right|left|right|l|r|L|R)(?P<rest>[A-Z].*)$", s))
    if m:
        side, s = m.group("pre").lower(), m.group("rest")
    else:
        m = (re.match(r"^(?P<rest>.+?)[_\- .]*(?P<post>left|right)$", s, re.IGNORECASE)
             or re.match(r"^(?P<rest>.+?)[_\- .]+(?P<post>l|r)$", s, re.IGNORECASE)
             or re.match(r"^(?P<rest>.+?[a-z])(?P<post>L|R)$", s))            # "EyeL", camel-glued
        if m:
            side, s = m.group("post").lower(), m.group("rest")
    if side in ("l", "r"):
        side = {"l": "left", "r": "right"}[side]
    return re.sub(r"[_\- .]+", "", s).lower(), side


def joint_role(name: str) -> str | None:
    """The face role of a skeleton joint from its name: one of :data:`JOINT_ROLES`, or None.

    Namespaces, exporters' prefixes and suffixes are looked through; ends, tips, twist and helper
    joints are never a role.

    Examples
    --------
    >>> [joint_role(n) for n in ("mixamorig:Head", "Bip01 Head", "J_Bip_C_Head", "DEF-neck", "HeadTop_End")]
    ['head', 'head', 'head', 'neck', None]
    >>> [joint_role(n) for n in ("RightEye", "J_Adj_L_FaceEye", "CC_Base_R_Eye", "eye.L", "neck_01", "Jaw")]
    ['rightEye', 'leftEye', 'rightEye', 'leftEye', 'neck', 'jaw']
    """
    if not isinstance(name, str) or not name.strip():
        return None
    base = re.split(r"[:|/]", name.strip())[-1]
    low = re.sub(r"^(?:def|org)[-_]", "", base, flags=re.IGNORECASE).lower()
    if low in _RIGIFY:
        return _RIGIFY[low]
    core, side = _joint_words(name)
    if not core or _JOINT_NOT.search(core):
        return None
    if side is None and core in ("head", "neck", "neck0", "neck00", "neck01", "neck1", "jaw", "jawroot",
                                 "lowerjaw", "jawbone", "mandible"):
        return {"head": "head", "jaw": "jaw", "jawroot": "jaw", "lowerjaw": "jaw", "jawbone": "jaw",
                "mandible": "jaw"}.get(core, "neck")
    if _EYE.match(core):
        if side is None:
            return None
        return "leftEye" if side == "left" else "rightEye"
    return None


def find_joints(names, parents=None) -> dict[str, int]:
    """Which joint plays each face role (:data:`JOINT_ROLES`) in a skeleton.

    Parameters
    ----------
    names : sequence of str
        Joint (or node) names.
    parents : sequence of int, optional
        Each joint's parent index (-1 for a root).  With it, a role claimed by several joints goes to
        the one nearest the root (the first neck of a neck chain, the head rather than a copy below
        it), and a neck is taken only when it is an ancestor of the head.

    Returns
    -------
    dict
        ``{role: index}`` for the roles found.

    Examples
    --------
    >>> find_joints(["Hips", "Spine", "Neck", "Neck1", "Head", "HeadTop_End", "LeftEye"], [-1, 0, 1, 2, 3, 4, 4])
    {'neck': 2, 'head': 4, 'leftEye': 6}
    """
    names = list(names)
    depth = None
    if parents is not None:
        parents = [int(p) for p in parents]
        depth = []
        for i in range(len(names)):
            d, p, seen = 0, parents[i], set()
            while p >= 0 and p not in seen and p < len(names):
                seen.add(p)
                d, p = d + 1, parents[p]
            depth.append(d)
    found: dict[str, list[int]] = {}
    for i, n in enumerate(names):
        r = joint_role(n)
        if r is not None:
            found.setdefault(r, []).append(i)
    out: dict[str, int] = {}
    for role in ("neck", "head", "jaw", "leftEye", "rightEye"):
        cands = found.get(role, [])
        if not cands:
            continue
        if depth is not None:
            cands = sorted(cands, key=lambda i: (depth[i], i))
        out[role] = cands[0]
    if parents is not None and "neck" in out and "head" in out:
        anc, p = set(), parents[out["head"]]
        while p >= 0 and p not in anc and p < len(names):
            anc.add(p)
            p = parents[p]
        if out["neck"] not in anc:
            chain = [i for i in found.get("neck", []) if i in anc]
            if chain:
                out["neck"] = min(chain, key=lambda i: (depth[i], i))
            else:
                del out["neck"]
    return out


# ------------------------------------------------------------------------------------- marker labels
#: Words of facial marker labels (found inside a label: ``Leye_Up``, ``NoseTop``, ``Mouth_Lend``).
_FACE_WORDS = ("brow", "eye", "lid", "lash", "cheek", "nose", "nostril", "nasal", "mouth", "lip", "jaw", "chin",
               "forehead", "philtrum", "temple", "dimple", "smile", "mentalis", "zygo")
#: Whole tokens of body marker labels: Vicon Plug-in Gait's codes (``LASI``, ``RKNE``, ``C7``, ``STRN``...,
#: with or without the side letter), and body parts (``L_THIGH_1``, ``R.Heel``, ``LeftKnee``).
_BODY_CODES = frozenset({"asi", "psi", "asis", "psis", "thi", "kne", "tib", "ank", "hee", "toe", "sho", "upa", "elb",
                         "frm", "wra", "wrb", "fin", "bak", "c7", "t8", "t10", "clav", "strn", "sacr", "mt", "mt1",
                         "mt2", "mt5", "mh1", "mh5", "gt", "lepi", "mepi", "lmal", "mmal"})
_BODY_WORDS = frozenset({"thigh", "knee", "shank", "tibia", "shin", "ankle", "heel", "toe", "toes", "foot", "feet",
                         "pelvis", "hip", "hips", "sacrum", "spine", "thorax", "chest", "sternum", "clavicle",
                         "shoulder", "acromion", "arm", "upperarm", "forearm", "elbow", "wrist", "hand", "finger",
                         "thumb", "leg", "calf", "femur", "trochanter", "malleolus", "waist", "navel", "belly",
                         "scapula", "iliac", "knuckle", "metatarsal"})


def marker_region(label: str) -> str | None:
    """Whether a marker label names a place on the face (``"face"``), on the body (``"body"``), or neither.

    Examples
    --------
    >>> [marker_region(s) for s in ("Leye_Up", "NoseTop", "Mouth_Lend", "LASI", "RKNE", "L_THIGH_1", "C7", "M001")]
    ['face', 'face', 'face', 'body', 'body', 'body', 'body', None]
    """
    if not isinstance(label, str) or not label.strip():
        return None
    low = label.lower()
    if any(w in low for w in _FACE_WORDS):
        return "face"
    words = re.sub(r"([a-z])([A-Z])", r"\1 \2", label.strip())
    tokens = [t for t in re.split(r"[^a-z0-9]+", words.lower()) if t]
    for t in tokens:
        core = re.sub(r"\d+$", "", t)
        if t in _BODY_CODES or t in _BODY_WORDS or core in _BODY_WORDS or (
                len(t) > 2 and t[0] in "lr" and (t[1:] in _BODY_CODES or t[1:] in _BODY_WORDS)):
            return "body"
        if t in ("left", "right", "l", "r") or t.isdigit():
            continue
    return None
