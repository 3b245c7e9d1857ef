"""What a character is and does, in one place (issue 33): read and written through the format registry
(:mod:`faceretarget.formats`, :func:`faceretarget.io.read_character`), its 68 landmarks found on a render and
cached (:func:`load_character`), the shapes that drive it and the one rig the solvers work on
(:func:`drive_rig`), its check picture (:func:`inspect_character`), and shapes generated for a neutral face
(:func:`generate_shapes`, with :mod:`faceretarget.transfer`'s deformation transfer).

It sits between the methods (capture, transfer, ...) and the pipelines: the pipelines, the CLI and the
Blender extension use it; nothing below it imports it (``tests/test_architecture.py``).
"""

from ._frame import (
    FACE_SYMMETRIC_PCT,
    FACE_TURN_DEG,
    PITCH_BIAS_DEG,
    PITCH_TOLERANCE_DEG,
    face_pitch_turn,
    face_turn,
    symmetry_plane,
)
from ._generate import EYE_LOOK_DEGREES, LID_PAIRS, LIP_PAIRS, METHODS, GeneratedShapes, generate_shapes
from ._load import (
    LANDMARKS_FORMAT,
    CharacterLook,
    CharacterReport,
    DriveRig,
    apply_landmark_record,
    character_look,
    character_weights,
    drive_rig,
    inspect_character,
    landmark_cache_path,
    landmark_record,
    load_character,
    look_rig,
    mesh_sha256,
    read_landmark_file,
)
from ._score_map import MIN_NAMED, ScorePrior, by_name, held_shapes, score_map
from ._template import load_template

__all__ = ["load_character", "drive_rig", "DriveRig", "look_rig", "character_look", "CharacterLook",
           "character_weights", "inspect_character",
           "CharacterReport", "landmark_cache_path", "landmark_record", "apply_landmark_record", "mesh_sha256",
           "read_landmark_file", "LANDMARKS_FORMAT", "generate_shapes", "GeneratedShapes", "load_template",
           "LID_PAIRS", "LIP_PAIRS", "EYE_LOOK_DEGREES", "METHODS", "score_map", "ScorePrior", "by_name", "held_shapes", "MIN_NAMED",
           "face_turn", "symmetry_plane", "FACE_TURN_DEG", "FACE_SYMMETRIC_PCT", "face_pitch_turn",
           "PITCH_BIAS_DEG", "PITCH_TOLERANCE_DEG"]
