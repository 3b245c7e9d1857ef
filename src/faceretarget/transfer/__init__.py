"""Expression shapes for a character that has only a neutral face (issue 25).

A template face with the ARKit shapes (ICT-FaceKit, packaged) is registered onto the character's face
(landmark similarity, thin-plate-spline warp, non-rigid ICP), and each template shape is transferred onto
the character's own topology by deformation transfer (Sumner & Popovic 2004: the template's per-triangle
deformation gradients, solved for the character's vertices with one sparse factorisation for all shapes).
Eyeballs turn for ``eyeLook*``, the lower teeth and tongue ride the jaw, lids close onto the character's own
eyeballs, the inner lips meet for ``jawOpen + mouthClose``.  See docs/shapes.md.
"""

from ..errors import moved_names
from ._geometry import closest_points, gradient_operator, triangle_areas, umeyama, vertex_normals
from ._metrics import (
    blink_gap_pct,
    eye_parts,
    inverted_triangles,
    lid_gap_pct,
    lip_gap_pct,
    lips_in_teeth,
    mirror_err_pct,
    shape_delta,
    shape_metrics,
    teeth_showing_px,
)
from ._parts import SEAM, LidMargin, Part, components, find_parts, fit_sphere, landmark_skin, lid_margins
from ._register import register_template
from ._template import TEMPLATES, Template, ict_to_arkit, packaged_template, packaged_template_path

__all__ = ["Template", "TEMPLATES", "ict_to_arkit", "packaged_template", "closest_points", "gradient_operator",
           "triangle_areas", "umeyama", "vertex_normals", "components", "landmark_skin",
           "packaged_template_path", "register_template", "find_parts", "fit_sphere", "Part", "LidMargin",
           "lid_margins", "blink_gap_pct", "lip_gap_pct", "inverted_triangles",
           "mirror_err_pct", "shape_metrics", "eye_parts", "shape_delta", "lips_in_teeth", "lid_gap_pct",
           "teeth_showing_px", "SEAM"]

#: Names that moved to :mod:`faceretarget.characters` (issue 33: generating a character's shapes is a
#: character job; this package keeps the method); they still work here for one release.
_MOVED = ("generate_shapes", "GeneratedShapes", "load_template", "LID_PAIRS", "LIP_PAIRS", "EYE_LOOK_DEGREES",
          "METHODS")


__getattr__ = moved_names(__name__, _MOVED, "faceretarget.characters")
