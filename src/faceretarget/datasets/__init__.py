"""Data made by the package: the embedded demo characters and evaluation data of the protocols.

================================ ================================================================
:mod:`._demo`                    the procedural demo characters ``ada`` and ``bo`` and seeded
                                 ARKit weight takes (``make demo``, tests)
:mod:`._paired_rigs`             P1 ground truth: paired rigs driven by the same weights, capture
                                 noise
:mod:`._styled_takes`            P3: styled takes with a known answer (emotion x speech content)
:mod:`._synthetic`               synthetic keyshape problems for the NNLS tests and benchmark
:mod:`._drawn_face`              a hand-drawn 2-D cartoon face as SVG key drawings (a drawing target)
================================ ================================================================

Nothing here is needed to retarget a user's take; the methods never import it.
"""

from ._demo import DEMO_CHARACTERS, demo_vertex_colors, make_demo_character, make_demo_take
from ._drawn_face import DRAWN_FACE_KEYS, drawn_face_svgs, write_drawn_face
from ._paired_rigs import ArkitPairing, add_capture_noise, keymodels_from_weights, rig_animation
from ._styled_takes import DEFAULT_WARPS, P3Takes, StyleWarp, content_channels, make_p3_takes
from ._synthetic import keyshape_problem, rom_problem

__all__ = [
    "DEMO_CHARACTERS", "make_demo_character", "demo_vertex_colors", "make_demo_take",
    "ArkitPairing", "add_capture_noise", "keymodels_from_weights", "rig_animation",
    "make_p3_takes", "P3Takes", "StyleWarp", "DEFAULT_WARPS", "content_channels",
    "keyshape_problem", "rom_problem", "DRAWN_FACE_KEYS", "drawn_face_svgs", "write_drawn_face",
]
