"""Head motion that follows the speech (Chuang 2004, Ch. 4).

Given new speech audio, :class:`HeadMotionDatabase` finds head motion that fits it in a database
of recorded phrases of speech with synchronised head motion and stitches it into one trajectory.

================================ ================================================================
:mod:`._pitch`                   Praat pitch (parselmouth), cleaned to a human range
:mod:`._segments`                phrases at pauses, segments from one pitch onset to the next
:mod:`._database`                :class:`HeadMotionDatabase`: matching (Eq. 4.3-4.5), path search,
                                 blending, range (:func:`rotation_range`)
:mod:`._viterbi`                 Viterbi over candidate segments with a reuse penalty
:mod:`._blend`                   time warp, chaining, drift correction of the chosen segments
================================ ================================================================

Head takes are :class:`~faceretarget.Performance` objects with audio and a
:class:`~faceretarget.HeadPose` (read by :func:`faceretarget.io.read_head_take`); see
``docs/headmotion.md``.
"""

from ._blend import blend_segments
from ._database import (
    EULER,
    RANGE_PERCENTILES,
    HeadMotionDatabase,
    HeadMotionResult,
    PathWeights,
    SynthesisInfo,
    rotation_range,
    take_duration,
)
from ._pitch import PitchTrack, extract_pitch
from ._segments import PHRASE_STATS, Segmentation, segment_speech
from ._viterbi import viterbi

__all__ = [
    "HeadMotionDatabase", "HeadMotionResult", "PathWeights", "SynthesisInfo", "EULER", "take_duration",
    "rotation_range", "RANGE_PERCENTILES",
    "PitchTrack", "extract_pitch", "Segmentation", "segment_speech", "PHRASE_STATS", "viterbi", "blend_segments",
]
