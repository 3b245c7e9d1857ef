"""The jobs file of ``faceretarget batch``: a TOML file read, checked and expanded into one job per
(input file, character) pair, before any work.

Layout (docs/batch.md has a full example)::

    out = "out/{character}/{take}.glb"      # output template of every job group (placeholders:
                                            # character, take, job, operation, parent)
    manifest = "out/batch.jsonl"            # default: batch.jsonl beside the jobs file

    [characters.ict]                        # a character: a rig folder, a .npz rig or a character file ...
    rig = "/work/shared/data/ict-face"
    [characters.bo]                         # ... a procedural demo character ...
    demo = "bo"
    [characters.hero]                       # ... and / or key-model (keyshape) pairs
    source_keys = "keys/actor"
    target_keys = "keys/hero"

    [[jobs]]
    name = "dialogue"                       # default "<operation>-<n>"
    operation = "clone"                     # clone | retarget | animate | headmotion-synth
    takes = ["takes/**/*.csv"]              # globs, relative to the jobs file
    exclude = ["*_rom*"]                    # optional fnmatch patterns (file name or relative path)
    characters = ["ict", "bo"]              # or "*"
    source = "arkit"                        # clone / retarget onto a rig: the rig the takes drive
    [jobs.options]                          # the operation's options (OPTIONS below)
    keys = "combined84"

Every mistake is an :class:`~faceretarget.errors.InvalidDataError` (or ``InputFileError``) naming
the jobs file and the key: ``jobs.toml: jobs #2 ('dialogue'), key 'options.method': ...``.  Nothing
here imports Dask: a jobs file is checked (``--dry-run``) without it.
"""

from __future__ import annotations

import fnmatch
import glob
import os
import re
import string
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ...errors import InputFileError, InvalidDataError
from ...files import read_text
from ...formats import BVH, C3D, NPZ, VIDEO_EXTENSIONS, WAV

__all__ = ["OPERATIONS", "OUTPUT_PLACEHOLDERS", "JOB_OPTIONS", "Character", "Job", "JobGroup", "BatchSpec",
           "read_jobs"]

#: What a job does with its input and character.
OPERATIONS = ("clone", "retarget", "animate", "headmotion-synth")
#: Placeholders of an output template: the character's name, the input's file stem, the job group's
#: name, the operation and the name of the input's folder.
OUTPUT_PLACEHOLDERS = ("character", "take", "job", "operation", "parent")
_ALIASES = {"headmotion synth": "headmotion-synth", "headmotion_synth": "headmotion-synth"}
_VIDEO = VIDEO_EXTENSIONS


# ------------------------------------------------------------------------------------ option checks
class _Bad(Exception):
    """A value refused by an option check (the caller adds the file and the key)."""


def _choice(*values: str) -> Callable:
    def check(v, root: Path):
        if not isinstance(v, str) or v not in values:
            raise _Bad(f"expected one of {', '.join(values)}, got {v!r}")
        return v
    return check


def _number(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
            integer: bool = False) -> Callable:
    def check(v, root: Path):
        ok = isinstance(v, int | float) and not isinstance(v, bool)
        if ok and integer:
            ok = float(v).is_integer()
        if not ok or v != v or v in (float("inf"), float("-inf")):
            raise _Bad(f"expected {'a whole number' if integer else 'a number'}, got {v!r}")
        if (lo is not None and (v <= lo if lo_open else v < lo)) or (hi is not None and v > hi):
            lo_s = "-inf" if lo is None else f"{lo:g}"
            hi_s = "inf" if hi is None else f"{hi:g}"
            raise _Bad(f"{v!r} is outside {'(' if lo_open else '['}{lo_s}, {hi_s}]")
        return int(v) if integer else float(v)
    return check


def _bool(v, root: Path):
    if not isinstance(v, bool):
        raise _Bad(f"expected true or false, got {v!r}")
    return v


def _resolve(root: Path, v) -> Path:
    p = Path(os.path.expanduser(str(v)))
    return p if p.is_absolute() else root / p


def _file(v, root: Path):
    if not isinstance(v, str) or not v:
        raise _Bad(f"expected a file path, got {v!r}")
    p = _resolve(root, v)
    if not p.is_file():
        raise _Bad(f"file not found: {p}")
    return p


def _keyset(v, root: Path):
    if not isinstance(v, str) or not re.fullmatch(r"arkit|emotions6|visemes13|combined84|rom-[1-9]\d*", v):
        raise _Bad(f"expected arkit, emotions6, visemes13, combined84 or rom-K, got {v!r}")
    return v


def _features(v, root: Path):
    if v in ("landmarks", "all"):
        return v
    return _file(v, root)


def _weight_range(v, root: Path):
    if v in ("auto", "none"):
        return None if v == "none" else "auto"
    if (isinstance(v, list) and len(v) == 2 and all(isinstance(x, int | float) and not isinstance(x, bool)
                                                    for x in v) and v[0] < v[1]):
        return (float(v[0]), float(v[1]))
    raise _Bad(f"expected \"auto\", \"none\" or [LO, HI] with LO < HI, got {v!r}")


def _word_or_file(words: tuple[str, ...], what: str):
    """A validator: one of ``words`` as it is, else an existing file (``what`` names it in the error)."""
    def check(v, root: Path):
        if v in words:
            return v
        try:
            return _file(v, root)
        except _Bad:
            raise _Bad(f"expected {quoted} or {what}, got {v!r}") from None

    quoted = ", ".join('"' + w + '"' for w in words)
    return check


_head_transfer = _word_or_file(("auto", "off"), "a head-motion file")


def _degrees(words: tuple[str, ...]):
    """A validator: one of ``words``, or how far a head turns: one number or [YAW, PITCH, ROLL] in [0, 360]
    degrees (a list of three)."""
    deg = _number(0, 360)

    def check(v, root: Path):
        if isinstance(v, str) and v in words:
            return v
        if isinstance(v, list) and len(v) == 3:
            return [deg(x, root) for x in v]
        if isinstance(v, int | float) and not isinstance(v, bool):
            return deg(v, root)
        quoted = "".join(f'"{w}", ' for w in words)
        raise _Bad(f"expected {quoted}degrees or [YAW, PITCH, ROLL] degrees, got {v!r}")

    return check


_regions = _word_or_file(("upper-lower", "default"), "a regions JSON file")


def _names(v, root: Path):
    if isinstance(v, str):
        v = [s.strip() for s in v.split(",") if s.strip()]
    if not isinstance(v, list) or not v or not all(isinstance(s, str) and s for s in v):
        raise _Bad(f"expected a list of marker names, got {v!r}")
    return tuple(v)


def _emotion(v, root: Path):
    if isinstance(v, str) and ":" not in v:             # a curve file
        return _file(v, root)
    if isinstance(v, str):
        return v
    raise _Bad(f"expected EMOTION:AMOUNT[,EMOTION:AMOUNT] or a curve file, got {v!r}")


def _pairs(v, root: Path):
    if (not isinstance(v, list) or not v
            or not all(isinstance(p, list) and len(p) == 2 and all(isinstance(x, str) for x in p) for p in v)):
        raise _Bad(f"expected a list of [\"SPEECH.wav\", \"MOTION\"] pairs, got {v!r}")
    return tuple((_file(a, root), _file(m, root)) for a, m in v)


#: Every operation's options: ``{name: (phase, check, default)}``.  ``"fit"`` options shape the model
#: fitted once per character (a change refits it and re-runs its jobs); ``"apply"`` options act per job.
JOB_OPTIONS: dict[str, dict[str, tuple[str, Callable, object]]] = {
    "clone": {
        "keys": ("fit", _keyset, "combined84"),
        "keys_from": ("fit", _file, None),
        "method": ("fit", _choice("temporal", "linear", "pyun"), "temporal"),
        "features": ("fit", _features, "landmarks"),
        "weight_range": ("fit", _weight_range, "auto"),
        "head": ("apply", _head_transfer, "auto"),
        "bake": ("apply", _bool, False),
    },
    "retarget": {
        "solver": ("fit", _choice("signed", "nnls"), "signed"),
        "weight_range": ("fit", _weight_range, "auto"),
        "l1": ("fit", _number(0), 0.0),
        "l2": ("fit", _number(0), 0.0),
        "temporal": ("fit", _number(0, 1000), 0.0),
        "denoise": ("fit", _bool, True),
        "smooth": ("fit", _number(0), 0.0),
        "regions": ("fit", _regions, None),
        "align": ("fit", _bool, True),
        "rigid_subset": ("fit", _names, None),
        "head": ("apply", _head_transfer, "auto"),
        "bake": ("apply", _bool, False),
    },
    "animate": {
        "style": ("fit", _file, None),
        "head": ("apply", _choice("video", "speech", "off"), "video"),
        "head_db": ("apply", _file, None),
        "head_amplitude": ("apply", _number(0, 10), 1.0),
        "head_range": ("apply", _degrees(("auto", "database")), "auto"),
        "emotion": ("apply", _emotion, None),
        "max_frames": ("apply", _number(1, integer=True), None),
        "bake": ("apply", _bool, False),
    },
    "headmotion-synth": {
        "db": ("fit", _file, None),
        "build": ("fit", _pairs, None),
        "build_fps": ("fit", _number(0, 1000, lo_open=True), 30.0),
        "pause": ("fit", _number(0, 5, lo_open=True), 0.3),
        "f0_min": ("fit", _number(0, lo_open=True), 60.0),
        "f0_max": ("fit", _number(0, lo_open=True), 500.0),
        "mirror": ("fit", _bool, True),
        "allow_mismatch": ("fit", _bool, False),
        "amplitude": ("apply", _number(0, 10), 1.0),
        "motion_range": ("apply", _degrees(()), None),
        "rotation": ("apply", _bool, True),
        "translation": ("apply", _bool, True),
        "seed": ("apply", _number(0, 2**32 - 1, integer=True), None),
        "fps": ("apply", _number(0, 1000, lo_open=True), None),
    },
}


# ------------------------------------------------------------------------------------ the spec
@dataclass(frozen=True)
class Character:
    """A character of the jobs file: its own rig (``rig`` folder / ``.npz`` / a character file such as ``.glb``,
    ``.vrm``, ``.fbx``, ``.blend``, ``.usd``, read as :class:`faceretarget.character.Character`, or a procedural
    ``demo`` character), and / or key-model or keyshape pairs (``source_keys`` / ``target_keys``
    folders, paired by file or shape name).  Paths are absolute."""

    name: str
    rig: Path | None = None
    demo: str | None = None
    neutral: str | None = None
    landmarks: Path | None = None
    source_keys: Path | None = None
    target_keys: Path | None = None
    source_neutral: str | None = None
    target_neutral: str | None = None
    source_landmarks: Path | None = None
    target_landmarks: Path | None = None

    @property
    def has_rig(self) -> bool:
        return self.rig is not None or self.demo is not None

    @property
    def has_keys(self) -> bool:
        return self.source_keys is not None

    def files(self) -> list[Path]:
        """Every file whose bytes define the character (rig and key folders, landmark files), sorted."""
        out: list[Path] = []
        for p in (self.rig, self.landmarks, self.source_keys, self.target_keys, self.source_landmarks,
                  self.target_landmarks):
            if p is None:
                continue
            if p.is_dir():
                out += sorted(f for f in p.rglob("*") if f.is_file() and not f.name.startswith("."))
            else:
                out.append(p)
        return out


@dataclass(frozen=True)
class JobGroup:
    """One ``[[jobs]]`` table: an operation over inputs x characters."""

    name: str
    index: int
    operation: str
    takes: tuple[str, ...]
    characters: tuple[str, ...]
    source: str | None
    out: str
    options: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Job:
    """One input onto one character.

    Attributes
    ----------
    id : str
        ``group:character:input`` (the input relative to the jobs file's folder when inside it).
    character : str
        The character's name (for ``headmotion-synth``, the database's name).
    input : Path
        The take, video, capture ``.npz`` or speech WAV.
    out : Path
        The output file.
    fit, apply : dict
        The options that shape the shared model and those applied per job (paths absolute).
    """

    id: str
    group: str
    operation: str
    character: str
    source: str | None
    input: Path
    out: Path
    fit: dict
    apply: dict

    @property
    def take(self) -> str:
        return self.input.stem

    @property
    def options(self) -> dict:
        return {**self.fit, **self.apply}


@dataclass(frozen=True)
class BatchSpec:
    """A jobs file read and expanded (:func:`read_jobs`)."""

    path: Path
    root: Path
    manifest: Path
    characters: dict[str, Character]
    groups: list[JobGroup]
    jobs: list[Job]


# ------------------------------------------------------------------------------------ reading
def _where_job(i: int, name: str | None) -> str:
    return f"jobs #{i}" + (f" ('{name}')" if name else "")


def _character(path: Path, root: Path, name: str, table) -> Character:
    where = f"{path}: characters.{name}"
    if not isinstance(table, dict):
        raise InvalidDataError(f"{where}: expected a table (rig = \"FOLDER\", demo = \"bo\" or "
                               "source_keys / target_keys), got {table!r}")
    allowed = {"rig", "demo", "neutral", "landmarks", "source_keys", "target_keys", "source_neutral",
               "target_neutral", "source_landmarks", "target_landmarks"}
    if unknown := sorted(set(table) - allowed):
        raise InvalidDataError(f"{where}: unknown key '{unknown[0]}' (use {', '.join(sorted(allowed))})")
    kw: dict = {}
    for key in ("rig", "source_keys", "target_keys"):
        if key in table:
            v = table[key]
            if not isinstance(v, str) or not v:
                raise InvalidDataError(f"{where}, key '{key}': expected a path, got {v!r}")
            p = _resolve(root, v)
            if not p.exists():
                raise InvalidDataError(f"{where}, key '{key}': not found: {p}")
            if key != "rig" and not p.is_dir():
                raise InvalidDataError(f"{where}, key '{key}': expected a folder, got the file {p}")
            kw[key] = p
    for key in ("landmarks", "source_landmarks", "target_landmarks"):
        if key in table:
            try:
                kw[key] = _file(table[key], root)
            except _Bad as e:
                raise InvalidDataError(f"{where}, key '{key}': {e}") from None
    for key in ("neutral", "source_neutral", "target_neutral"):
        if key in table:
            v = table[key]
            if not isinstance(v, str) or not v:
                raise InvalidDataError(f"{where}, key '{key}': expected an OBJ file name or path, got {v!r}")
            p = _resolve(root, v)
            kw[key] = str(p) if p.is_file() else v          # a path, or a file name inside the folder
    if "demo" in table:
        from ...datasets import DEMO_CHARACTERS

        if table["demo"] not in DEMO_CHARACTERS:
            raise InvalidDataError(f"{where}, key 'demo': expected one of {', '.join(DEMO_CHARACTERS)}, "
                                   f"got {table['demo']!r}")
        if "rig" in kw:
            raise InvalidDataError(f"{where}: give 'rig' or 'demo', not both")
        kw["demo"] = table["demo"]
    for key, needs in (("neutral", "rig"), ("landmarks", "rig"), ("source_neutral", "source_keys"),
                       ("target_neutral", "target_keys"), ("source_landmarks", "source_keys"),
                       ("target_landmarks", "target_keys")):
        if key in kw and needs not in kw:                  # read by nothing: a misplaced key, not a quiet default
            raise InvalidDataError(f"{where}, key '{key}': applies to '{needs}', which this character does not give"
                                   + (" (a demo character has its own)" if "demo" in kw and needs == "rig" else ""))
    if ("source_keys" in kw) != ("target_keys" in kw):
        raise InvalidDataError(f"{where}: give both 'source_keys' and 'target_keys' (key-model pairs)")
    if not kw.get("rig") and not kw.get("demo") and not kw.get("source_keys"):
        raise InvalidDataError(f"{where}: give 'rig' (a rig folder), 'demo' (ada, bo) or 'source_keys' + "
                               "'target_keys' (key-model pairs)")
    return Character(name=name, **kw)


def _strings(v, where: str, key: str) -> tuple[str, ...]:
    if isinstance(v, str):
        v = [v]
    if not isinstance(v, list) or not v or not all(isinstance(s, str) and s for s in v):
        raise InvalidDataError(f"{where}, key '{key}': expected a string or a list of strings, got {v!r}")
    return tuple(v)


def _options(path: Path, root: Path, where: str, op: str, table) -> tuple[dict, dict]:
    """``(fit, apply)`` options of a job group, every option present with its default filled in."""
    table = {} if table is None else table
    if not isinstance(table, dict):
        raise InvalidDataError(f"{where}, key 'options': expected a table, got {table!r}")
    spec = JOB_OPTIONS[op]
    if unknown := sorted(set(table) - set(spec)):
        raise InvalidDataError(f"{where}, key 'options.{unknown[0]}': unknown option of {op} "
                               f"(it has {', '.join(spec)})")
    fit, apply = {}, {}
    for key, (phase, check, default) in spec.items():
        if key in table:
            try:
                value = check(table[key], root)
            except _Bad as e:
                raise InvalidDataError(f"{where}, key 'options.{key}': {e}") from None
        else:
            value = default
        (fit if phase == "fit" else apply)[key] = value
    o = {**fit, **apply}

    def bad(key, msg):
        raise InvalidDataError(f"{where}, key 'options.{key}': {msg}")

    if op == "clone" and o["keys"].startswith("rom-") and o["keys_from"] is None:
        bad("keys", f"'{o['keys']}' needs a range-of-motion weight take (options.keys_from): a batch shares "
            "one key-model set across its takes")
    if op == "retarget":
        for key in ("temporal", "l1"):
            if o[key] and o["solver"] != "nnls":
                bad(key, f"{o[key]:g} applies to solver = \"nnls\" only")
    if op == "animate":
        if o["head"] == "speech" and o["head_db"] is None:
            bad("head", "\"speech\" needs a head-motion database (options.head_db)")
        if o["emotion"] is not None and o["style"] is None:
            bad("emotion", "needs a style model (options.style)")
    if op == "headmotion-synth":
        if (o["db"] is None) == (o["build"] is None):
            bad("db", "give 'db' (a database .npz) or 'build' (speech + motion pairs), one of them")
        if not o["f0_min"] < o["f0_max"]:
            bad("f0_min", f"{o['f0_min']:g} must be below f0_max {o['f0_max']:g}")
        if not (o["rotation"] or o["translation"]):
            bad("rotation", "rotation = false and translation = false leave nothing to write")
    return fit, apply


def _expand(path: Path, root: Path, where: str, patterns: tuple[str, ...], exclude: tuple[str, ...],
            exts: tuple[str, ...], op: str) -> list[Path]:
    """The files the glob ``patterns`` name (relative to ``root``; ``**`` recursive), minus ``exclude``."""
    found: dict[Path, None] = {}
    for pat in patterns:
        full = os.path.expanduser(pat)
        if os.path.isabs(full):
            hits = [Path(h) for h in sorted(glob.glob(full, recursive=True))]
        else:
            hits = [root / h for h in sorted(glob.glob(full, root_dir=root, recursive=True))]
        hits = [h for h in hits if h.is_file()]
        if not hits:
            raise InvalidDataError(f"{where}, key 'takes': '{pat}' matches no file (relative to {root})")
        for h in hits:
            found.setdefault(h, None)
    out = []
    for f in found:
        rel = os.path.relpath(f, root)
        if any(fnmatch.fnmatch(f.name, x) or fnmatch.fnmatch(rel, x) for x in exclude):
            continue
        if f.suffix.lower() not in exts:
            raise InvalidDataError(f"{where}, key 'takes': {f} is not an input {op} reads ({', '.join(exts)}); "
                                   "narrow the pattern or add it to 'exclude'")
        out.append(f)
    if not out:
        raise InvalidDataError(f"{where}, key 'exclude': excludes every file 'takes' matches")
    return out


def _input_exts(op: str) -> tuple[str, ...]:
    from ...io import READ_FORMATS

    if op in ("clone", "retarget"):
        return tuple(e for e in READ_FORMATS if e.startswith("."))
    if op == "animate":
        return _VIDEO + (NPZ, C3D)
    return (WAV,)


def _file_in_the_way(out: Path) -> Path | None:
    """The nearest existing ancestor of ``out`` when it is a regular file (no folder can be made there)."""
    for anc in out.parents:
        if anc.exists():
            return None if anc.is_dir() else anc
    return None


def _writes_back(rig: Path, out: Path) -> bool:
    from ...io import is_character_file, writes_back

    return is_character_file(rig) and writes_back(rig, out)


def _output_exts(op: str) -> tuple[str, ...]:
    from ...io import HEAD_FORMATS, WRITERS

    if op == "headmotion-synth":
        return HEAD_FORMATS
    return tuple(e for e in WRITERS if e.startswith(".") and e != BVH)


def _template(path: Path, where: str, template: str) -> str:
    if not isinstance(template, str) or not template:
        raise InvalidDataError(f"{where}, key 'out': expected an output path template such as "
                               "\"out/{character}/{take}.glb\", got {template!r}")
    try:
        names = [f for _, f, _, _ in string.Formatter().parse(template) if f is not None]
    except ValueError as e:
        raise InvalidDataError(f"{where}, key 'out': '{template}' is not a valid template ({e})") from None
    for n in names:
        if n not in OUTPUT_PLACEHOLDERS:
            raise InvalidDataError(f"{where}, key 'out': unknown placeholder {{{n}}} in '{template}' (use "
                                   f"{', '.join('{' + p + '}' for p in OUTPUT_PLACEHOLDERS)})")
    return template


def read_jobs(path: str | os.PathLike) -> BatchSpec:
    """Read a jobs file, check every key and expand it into jobs (before any work).

    Parameters
    ----------
    path : path-like
        The TOML jobs file (layout in this module's docstring and docs/batch.md).  Relative paths in
        it are relative to its folder.

    Returns
    -------
    BatchSpec
        Characters, job groups and one :class:`Job` per (input, character) pair (per input for
        ``headmotion-synth``), in file order.

    Raises
    ------
    InputFileError
        A missing file or one that is not TOML (with its line and column).
    InvalidDataError
        A key or value that is wrong, naming the file and the key: unknown keys, operations,
        characters, options or placeholders, values out of range, globs that match no file, inputs
        an operation cannot read, two jobs writing the same output.
    """
    path = Path(path)
    try:
        data = tomllib.loads(read_text(path))
    except tomllib.TOMLDecodeError as e:
        raise InputFileError(f"{path}: not a valid TOML jobs file ({e})") from None
    root = path.resolve().parent
    allowed = {"out", "manifest", "characters", "jobs"}
    if unknown := sorted(set(data) - allowed):
        raise InvalidDataError(f"{path}: unknown key '{unknown[0]}' (a jobs file has {', '.join(sorted(allowed))})")
    manifest = data.get("manifest", "batch.jsonl")
    if not isinstance(manifest, str) or not manifest.endswith(".jsonl"):
        raise InvalidDataError(f"{path}, key 'manifest': expected a .jsonl file path, got {manifest!r}")
    default_out = data.get("out")
    if default_out is not None:
        _template(path, str(path), default_out)
    chars_t = data.get("characters", {})
    if not isinstance(chars_t, dict):
        raise InvalidDataError(f"{path}, key 'characters': expected tables [characters.NAME]")
    characters = {n: _character(path, root, n, t) for n, t in chars_t.items()}
    groups_t = data.get("jobs")
    if not isinstance(groups_t, list) or not groups_t or not all(isinstance(g, dict) for g in groups_t):
        raise InvalidDataError(f"{path}, key 'jobs': expected one or more [[jobs]] tables")

    groups: list[JobGroup] = []
    jobs: list[Job] = []
    outputs: dict[Path, Job] = {}
    names_seen: set[str] = set()
    g_allowed = {"name", "operation", "takes", "exclude", "characters", "source", "out", "options"}
    for i, g in enumerate(groups_t, 1):
        where = f"{path}: {_where_job(i, g.get('name') if isinstance(g.get('name'), str) else None)}"
        if unknown := sorted(set(g) - g_allowed):
            raise InvalidDataError(f"{where}, key '{unknown[0]}': unknown key (a [[jobs]] table has "
                                   f"{', '.join(sorted(g_allowed))})")
        op = g.get("operation")
        op = _ALIASES.get(op, op) if isinstance(op, str) else op
        if op not in OPERATIONS:
            raise InvalidDataError(f"{where}, key 'operation': expected one of {', '.join(OPERATIONS)}, got {op!r}")
        name = g.get("name", f"{op}-{i}")
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_.\-]+", name):
            raise InvalidDataError(f"{where}, key 'name': expected letters, digits, '_', '-' or '.', got {name!r}")
        if name in names_seen:
            raise InvalidDataError(f"{where}, key 'name': '{name}' names two [[jobs]] tables")
        names_seen.add(name)
        if "takes" not in g:
            raise InvalidDataError(f"{where}: missing key 'takes' (glob patterns of the inputs)")
        takes = _strings(g["takes"], where, "takes")
        exclude = _strings(g["exclude"], where, "exclude") if "exclude" in g else ()
        out_t = _template(path, where, g.get("out", default_out) or "out/{character}/{take}.glb")
        fit, apply = _options(path, root, where, op, g.get("options"))

        source = g.get("source")
        if op == "headmotion-synth":
            if "characters" in g or source is not None:
                raise InvalidDataError(f"{where}, key '{'characters' if 'characters' in g else 'source'}': "
                                       "headmotion-synth writes head motion alone, from speech; remove it")
            label = Path(fit["db"]).stem if fit["db"] is not None else name
            chars = (label,)
        else:
            if "characters" not in g:
                raise InvalidDataError(f"{where}: missing key 'characters' (names from [characters], or \"*\")")
            chars = _strings(g["characters"], where, "characters")
            if chars == ("*",):
                chars = tuple(characters)
            for c in chars:
                if c not in characters:
                    raise InvalidDataError(f"{where}, key 'characters': no character '{c}' (the file defines "
                                           f"{', '.join(characters) or 'none'})")
            if source is not None:
                if not isinstance(source, str) or source not in characters:
                    raise InvalidDataError(f"{where}, key 'source': no character {source!r}")
                if not characters[source].has_rig:
                    raise InvalidDataError(f"{where}, key 'source': '{source}' has no rig ('rig' or 'demo') "
                                           "for the takes to drive")
            for c in chars:
                ch = characters[c]
                if op in ("clone", "retarget") and not ch.has_keys and (source is None or not ch.has_rig):
                    raise InvalidDataError(
                        f"{where}, key 'source': {op} onto the rig of '{c}' needs 'source', the character "
                        "whose rig the takes drive (key-models are paired on both rigs), or give "
                        f"'{c}' key-model pairs (source_keys / target_keys)")
                if op == "animate" and not ch.has_rig:
                    raise InvalidDataError(f"{where}, key 'characters': animate drives a character's rig; "
                                           f"'{c}' has none ('rig' or 'demo')")
        exts = _output_exts(op)
        groups.append(JobGroup(name, i, op, takes, chars, source, out_t, {**fit, **apply}))
        for f in _expand(path, root, where, takes, exclude, _input_exts(op), op):
            rel = os.path.relpath(f, root)
            shown = rel if not rel.startswith("..") else str(f)
            for c in chars:
                out = _resolve(root, out_t.format(character=c, take=f.stem, job=name, operation=op,
                                                  parent=f.parent.name))
                rig = characters[c].rig if c in characters else None
                if out.suffix.lower() not in exts and not (op != "headmotion-synth" and rig is not None
                                                           and _writes_back(rig, out)):
                    raise InvalidDataError(f"{where}, key 'out': {out}: {op} writes {', '.join(exts)}")
                if rig is not None and out.resolve() == rig.resolve():
                    raise InvalidDataError(f"{where}, key 'out': {out} is the character's own file")
                blocker = _file_in_the_way(out)
                if blocker is not None:
                    raise InvalidDataError(f"{where}, key 'out': {out} cannot be written: '{blocker}' is a file, "
                                           "not a folder")
                job = Job(f"{name}:{c}:{shown}", name, op, c, source, f, out, fit, apply)
                if out in outputs:
                    o = outputs[out]
                    raise InvalidDataError(f"{where}, key 'out': {out} is written by two jobs ({o.id} and {job.id}); "
                                           "add {parent} or {job} to the template")
                outputs[out] = job
                jobs.append(job)
    inputs = {j.input.resolve() for j in jobs}
    for out, job in outputs.items():
        if out.resolve() in inputs:
            raise InvalidDataError(f"{path}: {job.id}: the output {out} is an input of the batch")
    return BatchSpec(path=path, root=root, manifest=_resolve(root, manifest), characters=characters,
                     groups=groups, jobs=jobs)
