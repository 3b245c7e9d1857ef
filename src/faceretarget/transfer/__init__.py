"""Expression shapes for a character that has only a neutral face (issue 25).

A template face with the ARKit shapes (ICT-FaceKit, packaged) is registered onto the character's face
(landmark similarity, thin-plate-spline warp, non-rigid ICP), and each template shape is transferred onto
the character's own topology by deformation transfer (Sumner & Popovic 2004: the template's per-triangle
deformation gradients, solved for the character's vertices with one sparse factorisation for all shapes).
Eyeballs turn for ``eyeLook*``, the lower teeth and tongue ride the jaw, lids close onto the character's own
eyeballs, the inner lips meet for ``jawOpen + mouthClose``.  See docs/shapes.md.
"""

from ._metrics import (
    blink_gap_pct,
    eye_parts,
    inverted_triangles,
    lip_gap_pct,
    lips_in_teeth,
    mirror_err_pct,
    shape_delta,
    shape_metrics,
    teeth_showing_px,
)
from ._parts import LidMargin, Part, find_parts, fit_sphere, lid_margins
from ._register import register_template
from ._template import TEMPLATES, Template, ict_to_arkit, load_template, packaged_template_path
from ._transfer import EYE_LOOK_DEGREES, LID_PAIRS, LIP_PAIRS, METHODS, GeneratedShapes, generate_shapes

__all__ = ["generate_shapes", "GeneratedShapes", "load_template", "Template", "TEMPLATES", "ict_to_arkit",
           "packaged_template_path", "register_template", "find_parts", "fit_sphere", "Part", "LidMargin",
           "lid_margins", "LID_PAIRS",
           "LIP_PAIRS", "EYE_LOOK_DEGREES", "METHODS", "blink_gap_pct", "lip_gap_pct", "inverted_triangles",
           "mirror_err_pct", "shape_metrics", "eye_parts", "shape_delta", "lips_in_teeth",
           "teeth_showing_px"]
