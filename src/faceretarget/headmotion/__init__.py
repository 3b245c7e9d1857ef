"""Head motion that follows the speech (Chuang 2004, Ch. 4).

Given new speech audio, :class:`HeadMotionDatabase` finds head motion that fits it in a database
of recorded phrases of speech with synchronised head motion and stitches it into one trajectory.
See ``docs/headmotion.md``; conventions of the rotation angles in :mod:`._takes`.
"""

from ._blend import blend_segments
from ._database import HeadMotionDatabase, PathWeights, SynthesisInfo
from ._metrics import accent_onsets, angular_speed, beat_alignment, motion_beats, perlin_noise, pitch_peaks
from ._pitch import PitchTrack, extract_pitch
from ._segments import PHRASE_STATS, Segmentation, segment_speech
from ._takes import (
    EULER,
    HeadTake,
    head_motion_from_bvh,
    head_motion_from_markers,
    head_motion_from_smplx,
    mirror_head_motion,
    read_head_take,
)
from ._viterbi import viterbi
from ._write import head_quaternions, write_head_motion

__all__ = [
    "HeadMotionDatabase",
    "PathWeights",
    "SynthesisInfo",
    "HeadTake",
    "read_head_take",
    "head_motion_from_bvh",
    "head_motion_from_smplx",
    "head_motion_from_markers",
    "mirror_head_motion",
    "EULER",
    "PitchTrack",
    "extract_pitch",
    "Segmentation",
    "segment_speech",
    "PHRASE_STATS",
    "viterbi",
    "blend_segments",
    "write_head_motion",
    "head_quaternions",
    "angular_speed",
    "motion_beats",
    "accent_onsets",
    "pitch_peaks",
    "beat_alignment",
    "perlin_noise",
]
